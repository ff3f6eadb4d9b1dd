"""`obsbench` commands, one module each (LeRobot's `scripts/lerobot_*.py` layout): its parser next to its
handler, its own `main`. `lerobot_obsbench.cli` dispatches to them; nothing else imports them."""

# module names in `obsbench --help` order: simulation, the benchmark, the Hub, datasets and configs, real robots
COMMANDS = (
    "doctor",
    "demos",
    "replay",
    "import_h5",
    "import_rlbench",
    "eval",
    "eval_rlbench",
    "train",
    "run",
    "report",
    "convert_results",
    "push",
    "push_dataset",
    "validate",
    "encoders",
    "preset",
    "view",
    "attach_calibration",
    "find_cameras",
    "calibrate_cameras",
    "refine_cameras",
    "record",
    "rollout",
)
