"""Motion planning: the shared vocabulary (base.py: state space, validity checker, goal, problem,
result), the search tree (tree.py) and planar polygon kernels (polygons.py); the MASR's planners
(masr/: MASR-RRT* and RRT*, environments, plan files) and the soft arms' (soft/)."""
