"""ManiSkill3 tasks as gymnasium envs that speak the OBSBench schema.

`ObsBenchEnv.reset/step` return what stock `lerobot-eval` understands (`preprocess_observation` keeps only a
few keys), with the schema's extra sensors riding in the `robot_state` passthrough:

    pixels            {cam: uint8 (H, W, 3)}                 -> observation.images.<cam>
    agent_pos         float32 (16,): qpos (9) + tcp pose (7)  -> observation.state
    environment_state float32 (G,): the task goal, if any     -> observation.environment_state
    robot_state       {"depth.<cam>": uint16 (H, W, 1) mm, "intrinsics.<cam>": (3, 3), "cam2world.<cam>": (4, 4)}
                      -> observation.robot_state, unpacked by the plugin's policies into observation.<key>

`schema_frame(obs)` gives the same data keyed by dataset schema keys (used to record demonstrations), so a
policy trained on recorded demos runs unchanged on the env. Every step's info has `is_success` and the task's
sub-success milestones (achieved at any step so far).
"""

from __future__ import annotations

import os

import gymnasium as gym
import numpy as np

from lerobot_obsbench.datasets import schema
from lerobot_obsbench.envs.perturbations import apply_scene_perturbation, camera_overrides, parse_perturbation
from lerobot_obsbench.envs.tasks import TaskError, asset_help, missing_assets, task_spec

CONTROL_MODES = ("pd_ee_delta_pose", "pd_joint_pos")
STATE_DIM = 16


class RenderingError(RuntimeError):
    """SAPIEN found no usable Vulkan driver."""


RENDERING_HELP = (
    "ManiSkill renders through Vulkan and found no usable driver. On a CPU-only Debian 12 machine install Mesa "
    "25's lavapipe from bookworm-backports: `bash scripts/setup_system.sh` (as root), then check with "
    "`obsbench doctor`."
)


def import_maniskill(asset_dir: str | None = None):
    """Import ManiSkill's task registry, pointing it at `asset_dir` (must happen before the first import)."""
    if asset_dir:
        asset_dir = os.path.abspath(os.path.expanduser(asset_dir))
        import sys

        if "mani_skill" in sys.modules and os.environ.get("MS_ASSET_DIR") != asset_dir:
            raise TaskError(
                f"ManiSkill was already imported with MS_ASSET_DIR={os.environ.get('MS_ASSET_DIR')!r}; set "
                f"MS_ASSET_DIR={asset_dir} before starting the process instead of --env.asset_dir."
            )
        os.environ["MS_ASSET_DIR"] = asset_dir
    import mani_skill.envs  # noqa: F401  (registers the tasks)

    return mani_skill.envs


def to_numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def cam2world_from_extrinsic(extrinsic_cv: np.ndarray) -> np.ndarray:
    """OpenCV camera -> world (4, 4) from ManiSkill's world -> OpenCV camera extrinsic (3, 4)."""
    world2cam = np.eye(4)
    world2cam[:3] = extrinsic_cv
    return np.linalg.inv(world2cam).astype(np.float32)


def opencv_intrinsics(sapien_K: np.ndarray) -> np.ndarray:
    """SAPIEN's `intrinsic_cv` puts pixel centres at half-integers (cx = W/2 for a centred camera); the schema
    uses OpenCV's convention (centres at integers), so the principal point moves by half a pixel. Without this,
    unprojected points are off by half a pixel (~8 mm at 0.5 m for a 64² camera with a 90° field of view)."""
    K = np.array(sapien_K, dtype=np.float32)
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    return K


class ObsBenchEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, task: str, cameras=("base_camera",), image_size: int = 128,
                 control_mode: str = "pd_ee_delta_pose", asset_dir: str | None = None, seed: int | None = None,
                 episode_length: int | None = None, render_mode: str | None = "rgb_array",
                 perturbation: str | None = None):
        spec = task_spec(task)
        if control_mode not in CONTROL_MODES:
            raise ValueError(f"control_mode must be one of {CONTROL_MODES}; got {control_mode!r}")
        import_maniskill(asset_dir)
        if missing_assets(spec):
            raise TaskError(asset_help(spec, asset_dir or os.environ.get("MS_ASSET_DIR")))
        self.spec_ = spec
        self.cameras = list(cameras)
        self.image_size = image_size
        self.render_mode = render_mode
        self.task = spec.description
        self.task_description = spec.description
        self._next_seed = seed
        self.perturbation = parse_perturbation(perturbation)
        sensor_configs = dict(width=image_size, height=image_size)
        if self.perturbation and self.perturbation.kind == "noise":
            import sapien

            sapien.render.set_ray_tracing_samples_per_pixel(int(self.perturbation.scalar))
            sapien.render.set_ray_tracing_denoiser("none")
            sensor_configs["shader_pack"] = "rt"
        obs = self._make(task, control_mode, sensor_configs, episode_length or spec.max_steps)
        if self.perturbation and self.perturbation.kind.startswith("camera"):
            sensor_configs.update(camera_overrides(self._env.unwrapped, self.cameras, self.perturbation))
            self._env.close()
            obs = self._make(task, control_mode, sensor_configs, episode_length or spec.max_steps)
        if self.perturbation and self.perturbation.kind in ("light", "background"):
            apply_scene_perturbation(self._env.unwrapped, self.perturbation)
        available = list(obs["sensor_data"])
        unknown = [c for c in self.cameras if c not in available]
        if unknown:
            raise ValueError(f"{task} has no camera {unknown}; its cameras are {available} (--env.cameras).")
        self.unwrapped_ms = self._env.unwrapped
        self.action_space = gym.spaces.Box(-1.0, 1.0, self.unwrapped_ms.single_action_space.shape, np.float32)
        goal_dim = sum(int(np.prod(obs["extra"][k].shape[1:])) for k in spec.goal_keys)
        size = (image_size, image_size)
        spaces = {
            "pixels": gym.spaces.Dict({c: gym.spaces.Box(0, 255, (*size, 3), np.uint8) for c in self.cameras}),
            "agent_pos": gym.spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32),
            "robot_state": gym.spaces.Dict({
                **{f"depth.{c}": gym.spaces.Box(0, 65535, (*size, 1), np.uint16) for c in self.cameras},
                **{f"intrinsics.{c}": gym.spaces.Box(-np.inf, np.inf, (3, 3), np.float32) for c in self.cameras},
                **{f"cam2world.{c}": gym.spaces.Box(-np.inf, np.inf, (4, 4), np.float32) for c in self.cameras},
            }),
        }
        if goal_dim:
            spaces["environment_state"] = gym.spaces.Box(-np.inf, np.inf, (goal_dim,), np.float32)
        self.observation_space = gym.spaces.Dict(spaces)
        self._milestones: dict[str, bool] = {}

    def _make(self, task: str, control_mode: str, sensor_configs: dict, max_steps: int) -> dict:
        try:
            self._env = gym.make(task, obs_mode="rgb+depth", control_mode=control_mode, render_mode="rgb_array",
                                 sensor_configs=sensor_configs, num_envs=1, max_episode_steps=max_steps)
            obs, _ = self._env.reset(seed=0)
        except RuntimeError as err:
            if any(word in str(err).lower() for word in ("vulkan", "vk::", "render")):
                raise RenderingError(f"{RENDERING_HELP} (SAPIEN: {err})") from err
            raise
        return obs

    # ---- observation conversion --------------------------------------------------------------------------

    def schema_frame(self, obs: dict) -> dict[str, np.ndarray]:
        """ManiSkill observation (batch of 1) -> dataset schema keys (DESIGN §3)."""
        frame = {}
        for cam in self.cameras:
            data, param = obs["sensor_data"][cam], obs["sensor_param"][cam]
            frame[f"observation.images.{cam}"] = to_numpy(data["rgb"][0]).astype(np.uint8)
            frame[f"observation.depth.{cam}"] = np.clip(to_numpy(data["depth"][0]), 0, None).astype(np.uint16)
            frame[f"observation.intrinsics.{cam}"] = opencv_intrinsics(to_numpy(param["intrinsic_cv"][0]))
            frame[f"observation.cam2world.{cam}"] = cam2world_from_extrinsic(to_numpy(param["extrinsic_cv"][0]))
        state = np.concatenate([to_numpy(obs["agent"]["qpos"][0]), to_numpy(obs["extra"]["tcp_pose"][0])])
        frame["observation.state"] = state.astype(np.float32)
        if self.spec_.goal_keys:
            goal = [to_numpy(obs["extra"][k][0]).reshape(-1) for k in self.spec_.goal_keys]
            frame["observation.environment_state"] = np.concatenate(goal).astype(np.float32)
        return frame

    to_env_observation = staticmethod(schema.frame_to_env_observation)

    # ---- gym API -----------------------------------------------------------------------------------------

    def _info(self, info: dict) -> dict:
        success = bool(to_numpy(info["success"]).reshape(-1)[0]) if "success" in info else False
        for name in self.spec_.sub_success:
            self._milestones[name] = self._milestones.get(name, False) or self._milestone(name, info, success)
        return {"is_success": success, **{f"sub_success/{k}": v for k, v in self._milestones.items()}}

    def _milestone(self, name: str, info: dict, success: bool) -> bool:
        env = self.unwrapped_ms
        if name == "insert":
            return success
        if name == "grasp":
            obj = {"StackCube-v1": "cubeA", "PegInsertionSide-v1": "peg", "PlugCharger-v1": "charger"}[self.spec_.name]
            return bool(to_numpy(env.agent.is_grasping(getattr(env, obj))).reshape(-1)[0])
        if name == "align":  # peg head within the hole's cross-section (before or while inserting)
            head = to_numpy(info["peg_head_pos_at_hole"]).reshape(-1)
            radius = float(to_numpy(env.box_hole_radii).reshape(-1)[0])
            return bool(abs(head[1]) <= radius and abs(head[2]) <= radius and head[0] >= -0.05)
        raise KeyError(name)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is None and self._next_seed is not None:
            seed, self._next_seed = self._next_seed, self._next_seed + 1
        obs, info = self._env.reset(seed=seed, options=options)
        self._milestones = {}
        return self.to_env_observation(self.schema_frame(obs)), self._info(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self._env.step(np.asarray(action, dtype=np.float32))
        return (self.to_env_observation(self.schema_frame(obs)), float(to_numpy(reward).reshape(-1)[0]),
                bool(to_numpy(terminated).reshape(-1)[0]), bool(to_numpy(truncated).reshape(-1)[0]), self._info(info))

    def raw_observation(self) -> dict:
        """The current ManiSkill observation (batch of 1), e.g. to record a frame after reset/step."""
        return self.unwrapped_ms.get_obs()

    def render(self):
        return to_numpy(self._env.render())[0]

    def close(self):
        self._env.close()


def make_obsbench_env(task: str, **kwargs) -> ObsBenchEnv:
    return ObsBenchEnv(task, **kwargs)
