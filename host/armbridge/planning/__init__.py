"""Motion planning for the MASR (masr paper, section IV): environments, collision checking,
MASR-RRT* and the baseline RRT*, plan files and figures."""
