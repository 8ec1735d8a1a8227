"""MASR planning (masr paper, section IV) in the planning vocabulary (planning.base).

* space.py: MasrSpace (C_f of eq. 5, the action cost of eq. 8, Steer), MasrChecker
  (CollisionFree along the motion convention), MasrGoal (the goal check over the joint margin);
* collision.py: the numba collision kernels and CollisionChecker;
* environment.py: environments (JSON), the fixed E1-E3 (envs/); random_env.py: section V-C's random ones;
* kernels.py: MASR-RRT*'s numba kernels (Nearest + Steer, Extend with Connect / OnGoal / GoalFix / Rewire);
* rrt_star.py: `plan` (MASR-RRT* and the baseline RRT*, Algorithms 1-2) and its PlanResult;
* plan_file.py: MASR plan files (docs/formats.md);
* ompl_compare.py: OMPL's RRT* with the same checker and cost.

The numeric IK they use (goal configurations, the fallback goal IK) is armbridge.ik.masr_dls.
"""
