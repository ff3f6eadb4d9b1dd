"""Meta-World (MuJoCo) tasks as OBSBench tasks, beside the ManiSkill ones: LeRobot's own Meta-World task list
(`tasks.py`), the env that renders what the plugin's sensor schema needs (`env.py`: colour, metric depth, the
camera's intrinsics and pose, the robot state, the oracle's object poses) and the headless OpenGL it renders with
(`rendering.py`).

Importing this package is cheap: Meta-World and MuJoCo are imported only when an env is made.
"""
