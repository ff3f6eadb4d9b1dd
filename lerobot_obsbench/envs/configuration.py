"""`--env.type=obsbench`: the OBSBench ManiSkill3 tasks as a LeRobot EnvConfig; and one named env type per task
(`--env.type=obsbench_pickcube` = `--env.type=obsbench --env.task=PickCube-v1`)."""

from __future__ import annotations

from dataclasses import dataclass, field, make_dataclass

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_obsbench.envs.base_task import TASKS, check_cameras, task_spec
from lerobot_obsbench.envs.maniskill import ACTION_DIMS, CONTROL_FPS, CONTROL_MODES, DEFAULT_CONTROL_MODE, STATE_DIM
from lerobot_obsbench.envs.perturbations import parse_perturbation
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.numeric import check_number
from lerobot_obsbench.schema import ACTION_KEY, ENV_STATE_KEY, MIN_IMAGE_SIZE, STATE_KEY, image_key


@EnvConfig.register_subclass("obsbench")
@dataclass
class ObsBenchEnvConfig(EnvConfig):
    """ManiSkill3 task returning the OBSBench sensor frame (rgb, uint16 depth, K, cam2world, state, goal)."""

    # Task name (`obsbench doctor` lists them): PickCube-v1, StackCube-v1, PegInsertionSide-v1, PushCube-v1,
    # PullCube-v1, LiftPegUpright-v1, PlugCharger-v1, TurnFaucet-v1 (needs downloaded assets).
    task: str = "PickCube-v1"
    # Control frequency of ManiSkill's tabletop tasks.
    fps: int = CONTROL_FPS
    # Cameras to render (the paper: the single front `base_camera`).
    cameras: list[str] = field(default_factory=lambda: ["base_camera"])
    # Square image size of every camera (the paper: 128).
    image_size: int = 128
    # Robot controller: pd_ee_delta_pose (paper; 7-D action) or pd_joint_pos (8-D).
    control_mode: str = DEFAULT_CONTROL_MODE
    # Steps per episode; None = ManiSkill's budget for the task.
    episode_length: int | None = None
    # First seed used when reset() is called without one (then +1 per episode); None = unseeded.
    seed: int | None = None
    # Directory with ManiSkill's downloaded assets (MS_ASSET_DIR), needed by TurnFaucet-v1 only.
    asset_dir: str | None = None
    # Zero-shot evaluation perturbation `kind:value` (camera_yaw:5, camera_pitch:10, light:0.03,
    # background:1,0.2,0.2, noise:16; see lerobot_obsbench/envs/perturbations.py); None = the nominal scene.
    perturbation: str | None = None

    def __post_init__(self):
        spec = task_spec(self.task)
        parse_perturbation(self.perturbation)  # a typo fails here, not after the policy loaded
        check_cameras(spec, self.cameras)
        if self.control_mode not in CONTROL_MODES:
            raise ConfigError(f"control_mode must be one of {CONTROL_MODES}; got {self.control_mode!r}")
        check_number("image_size (pixels)", self.image_size, whole=True, minimum=MIN_IMAGE_SIZE)
        check_number("fps", self.fps, whole=True, minimum=1)
        if self.episode_length is not None:  # 0 would mean the task's own budget: refused rather than reinterpreted
            check_number(
                "episode_length (steps; or None for the task's own)", self.episode_length, whole=True, minimum=1
            )
        if self.seed is not None:
            check_number("seed (or None)", self.seed, whole=True, minimum=0)
        size = (self.image_size, self.image_size, 3)
        self.features = {
            "action": PolicyFeature(FeatureType.ACTION, (ACTION_DIMS[self.control_mode],)),
            "agent_pos": PolicyFeature(FeatureType.STATE, (STATE_DIM,)),
        }
        self.features_map = {"action": ACTION_KEY, "agent_pos": STATE_KEY}
        for cam in self.cameras:
            self.features[f"pixels/{cam}"] = PolicyFeature(FeatureType.VISUAL, size)
            self.features_map[f"pixels/{cam}"] = image_key(cam)
        if spec.goal:
            self.features["environment_state"] = PolicyFeature(FeatureType.ENV, (sum(spec.goal.values()),))
            self.features_map["environment_state"] = ENV_STATE_KEY

    @property
    def package_name(self) -> str:
        return "lerobot_obsbench.envs"

    @property
    def gym_id(self) -> str:
        return f"obsbench/{self.task}"

    @property
    def gym_kwargs(self) -> dict:
        steps = task_spec(self.task).max_steps if self.episode_length is None else self.episode_length
        # `max_episode_steps` is gym.make's TimeLimit (lerobot-eval reads it); `episode_length` reaches ManiSkill.
        return {
            "cameras": list(self.cameras),
            "image_size": self.image_size,
            "control_mode": self.control_mode,
            "asset_dir": self.asset_dir,
            "seed": self.seed,
            "episode_length": steps,
            "max_episode_steps": steps,
            "perturbation": self.perturbation,
        }


def _task_stem(task: str) -> str:
    """`PickCube-v1` -> `PickCube`."""
    return task.rsplit("-v", 1)[0].replace("-", "")


def env_type_name(task: str) -> str:
    """`PickCube-v1` -> `obsbench_pickcube`: the task's own `--env.type`."""
    return "obsbench_" + _task_stem(task).lower()


def _named_post_init(self) -> None:
    expected = NAMED_ENVS[self.type]
    if self.task != expected:
        raise ConfigError(
            f"--env.type={self.type} is the task {expected}; got --env.task={self.task}. Use "
            f"--env.type={env_type_name(self.task)}, or --env.type=obsbench with --env.task."
        )
    ObsBenchEnvConfig.__post_init__(self)


def _named_env(task: str) -> type:
    cls = make_dataclass(
        "ObsBench" + _task_stem(task) + "EnvConfig",
        [("task", str, field(default=task))],
        bases=(ObsBenchEnvConfig,),
        namespace={
            "__post_init__": _named_post_init,
            "__doc__": f"`--env.type=obsbench --env.task={task}` under its own name.",
            "__module__": __name__,
        },
    )
    return EnvConfig.register_subclass(env_type_name(task))(cls)


# One env type per OBSBench task (`obsbench_pickcube`, `obsbench_stackcube`, ...): `obsbench` with the task fixed.
NAMED_ENVS = {env_type_name(task): task for task in TASKS}
NAMED_ENV_CONFIGS = {name: _named_env(task) for name, task in NAMED_ENVS.items()}
