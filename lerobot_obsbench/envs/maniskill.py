"""ManiSkill3 tasks as gymnasium envs that speak the OBSBench schema.

`ObsBenchEnv.reset/step` return what stock `lerobot-eval` understands (`preprocess_observation` keeps only a
few keys), with the schema's extra sensors riding in the `robot_state` passthrough:

    pixels            {cam: uint8 (H, W, 3)}                 -> observation.images.<cam>
    agent_pos         float32 (16,): qpos (9) + tcp pose (7)  -> observation.state
    environment_state float32 (G,): the task goal, if any     -> observation.environment_state
    robot_state       {"depth.<cam>": uint16 (H, W, 1) mm, "intrinsics.<cam>": (3, 3), "cam2world.<cam>": (4, 4),
                       "privileged_state": (7 * O,) object poses, for tasks that name them}
                      -> observation.robot_state, unpacked by the plugin's policies into observation.<key>

`schema_frame(obs)` gives the same data keyed by dataset schema keys (used to record demonstrations), so a
policy trained on recorded demos runs unchanged on the env. Every step's info has `is_success` and the task's
sub-success milestones (achieved at any step so far).

One `ObsBenchEnv` can hold `num_envs` envs, in ManiSkill's GPU simulation (`sim_backend="physx_cuda"`):
`reset_all(seeds)`, `step_all(actions)` and `render_all()` take and give batches of tensors on its device (what
lockstep evaluation on a GPU feeds the policy). The gym API above is the same code at one env, its first row
turned into NumPy arrays.
"""

from __future__ import annotations

import os

import gymnasium as gym
import numpy as np

from lerobot_obsbench.envs.base_task import (
    Task,
    TaskError,
    asset_help,
    check_cameras,
    missing_assets,
    task_spec,
    to_numpy,
)
from lerobot_obsbench.envs.perturbations import (
    MANISKILL_KINDS,
    DepthNoiser,
    Perturbation,
    apply_scene_perturbation,
    camera_overrides,
    check_supported,
    parse_perturbation,
)
from lerobot_obsbench.errors import ConfigError, ObsBenchError, UsageError
from lerobot_obsbench.schema import (
    ENV_STATE_KEY,
    MIN_IMAGE_SIZE,
    POSE_SIZE,
    PRIVILEGED_STATE_KEY,
    STATE_KEY,
    cam2world_key,
    depth_key,
    frame_to_env_observation,
    image_key,
    intrinsics_key,
)

CONTROL_FPS = Task.fps
ROBOT_TYPE = Task.robot_type
# Controller -> action size; the paper's is the first (Δpos, Δrot axis-angle, gripper).
ACTION_DIMS = {"pd_ee_delta_pose": 7, "pd_joint_pos": 8}
CONTROL_MODES = tuple(ACTION_DIMS)
# ManiSkill's simulation backends: one env per process on the CPU, many per process on a GPU
SIM_BACKENDS = ("physx_cpu", "physx_cuda")
DEFAULT_CONTROL_MODE = CONTROL_MODES[0]
STATE_DIM = 16  # qpos (9) + TCP pose (7)


class RenderingError(ObsBenchError, RuntimeError):
    """SAPIEN found no usable Vulkan driver."""


class GpuSimulationError(ObsBenchError, RuntimeError):
    """ManiSkill's GPU simulation could not start: SAPIEN has no GPU PhysX library and could not fetch one."""


class BatchedEnvError(ObsBenchError, RuntimeError):
    """A one-env call (reset, step, render) on an env that holds several."""


def physx_gpu_library():
    """Where SAPIEN loads its GPU PhysX library from: it downloads it there from GitHub at the first GPU
    simulation."""
    from pathlib import Path

    import sapien.physx

    return Path.home() / ".sapien" / "physx" / sapien.physx.version() / "libPhysXGpu_64.so"


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
    import mani_skill.envs

    return mani_skill.envs


def cam2world_from_extrinsic(extrinsic_cv):
    """OpenCV camera -> world (..., 4, 4) float32 from ManiSkill's world -> OpenCV camera extrinsics (..., 3, 4)
    (a tensor on any device; inverted in float64)."""
    import torch

    world2cam = torch.eye(4, dtype=torch.float64, device=extrinsic_cv.device).expand(*extrinsic_cv.shape[:-2], 4, 4)
    world2cam = world2cam.clone()
    world2cam[..., :3, :] = extrinsic_cv.double()
    return torch.linalg.inv(world2cam).float()


def opencv_intrinsics(sapien_K):
    """SAPIEN's `intrinsic_cv` (..., 3, 3) puts pixel centres at half-integers (cx = W/2 for a centred camera); the
    schema uses OpenCV's convention (centres at integers), so the principal point moves by half a pixel. Without
    this, unprojected points are off by half a pixel (~8 mm at 0.5 m for a 64² camera with a 90° field of view)."""
    K = sapien_K.float().clone()
    K[..., 0, 2] -= 0.5
    K[..., 1, 2] -= 0.5
    return K


def render_backend(device: str | None) -> str:
    """ManiSkill's render backend for a torch device: the GPU for cuda devices, else SAPIEN's CPU renderer;
    None: a GPU when one is visible."""
    if device is None:
        import torch

        device = "cuda" if torch.cuda.is_available() else "cpu"
    return device if device.startswith("cuda") else "cpu"


def check_sim_backend(sim_backend: str | None, num_envs: int, render_device: str) -> str:
    """ManiSkill's simulation for `num_envs` envs in one process: its CPU simulation holds one env per process,
    its GPU simulation (physx_cuda) many, and needs a CUDA device. None: the one that can hold them."""
    if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
        raise UsageError(f"num_envs must be a whole number >= 1; got {num_envs!r}")
    sim_backend = sim_backend or ("physx_cuda" if num_envs > 1 else "physx_cpu")
    if sim_backend not in SIM_BACKENDS:
        raise UsageError(f"sim_backend must be one of {SIM_BACKENDS}; got {sim_backend!r}")
    if sim_backend == "physx_cuda" and render_device == "cpu":
        raise UsageError(
            "ManiSkill's GPU simulation (physx_cuda) needs a CUDA device (device='cuda'). On a CPU, envs run in "
            "lockstep one per worker process instead (obsbench eval --eval.batch_size N)."
        )
    if sim_backend == "physx_cpu" and num_envs > 1:
        raise UsageError(f"ManiSkill's CPU simulation holds one env per process; got num_envs={num_envs}")
    return sim_backend


def check_env_options(control_mode: str, image_size: int) -> None:
    """Refuse a controller or an image size ManiSkill cannot run, before the slow import of ManiSkill."""
    if control_mode not in CONTROL_MODES:
        raise ConfigError(f"control_mode must be one of {CONTROL_MODES}; got {control_mode!r}")
    if not isinstance(image_size, int) or image_size < MIN_IMAGE_SIZE:
        raise ConfigError(f"image_size must be a whole number of pixels >= {MIN_IMAGE_SIZE}; got {image_size!r}")


def import_task(spec, asset_dir: str | None) -> None:
    """Import ManiSkill pointed at `asset_dir` and refuse a task whose assets are not there, naming how to fetch
    them, since ManiSkill would otherwise fail deep inside scene loading."""
    import_maniskill(asset_dir)
    if missing_assets(spec):
        raise TaskError(asset_help(spec, asset_dir or os.environ.get("MS_ASSET_DIR")))


def check_perturbation(perturbation: Perturbation | None, num_envs: int) -> Perturbation | None:
    """Refuse the noise perturbation in a batched env: it renders with ray tracing, which ManiSkill runs for one
    env per process only."""
    if num_envs > 1 and perturbation and perturbation.kind == "noise":
        raise UsageError(
            f"{perturbation.name} renders with ray tracing, which ManiSkill runs for one env per process "
            "only: evaluate it with num_envs=1 (lockstep on CPU workers: --policy.device=cpu)."
        )
    return perturbation


def task_sensor_configs(spec, image_size: int) -> dict:
    """ManiSkill's `sensor_configs` for a task: every camera at `image_size`, and the task's own `base_camera`
    (pose and field of view) in place of ManiSkill's where the task sets one to frame its workspace."""
    configs = dict(width=image_size, height=image_size)
    if spec.camera is not None:
        from mani_skill.utils import sapien_utils

        eye, target, fov = spec.camera
        configs["base_camera"] = {"pose": sapien_utils.look_at(list(eye), list(target)), "fov": fov}
    return configs


def use_ray_tracing(samples_per_pixel: int, sensor_configs: dict) -> None:
    """Render the cameras with ray tracing at `samples_per_pixel` and no denoiser (the noise perturbation): the
    Monte-Carlo noise left in the colour image is the perturbation. SAPIEN's sampling settings are global, so
    they hold for every env this process makes afterwards."""
    import sapien

    sapien.render.set_ray_tracing_samples_per_pixel(samples_per_pixel)
    sapien.render.set_ray_tracing_denoiser("none")
    sensor_configs["shader_pack"] = "rt"


def observation_space(spec, cameras: list[str], image_size: int) -> gym.spaces.Dict:
    """The gym space of what `ObsBenchEnv.reset/step` return (the keys of the module docstring): each read
    camera's colour, depth and calibration, the robot state, the task's object poses and goal where it has them."""
    size = (image_size, image_size)
    privileged = {}
    if spec.privileged_actors:
        shape = (len(spec.privileged_actors) * POSE_SIZE,)
        privileged["privileged_state"] = gym.spaces.Box(-np.inf, np.inf, shape, np.float32)
    spaces = {
        "pixels": gym.spaces.Dict({c: gym.spaces.Box(0, 255, (*size, 3), np.uint8) for c in cameras}),
        "agent_pos": gym.spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32),
        "robot_state": gym.spaces.Dict(
            {
                **{f"depth.{c}": gym.spaces.Box(0, 65535, (*size, 1), np.uint16) for c in cameras},
                **{f"intrinsics.{c}": gym.spaces.Box(-np.inf, np.inf, (3, 3), np.float32) for c in cameras},
                **{f"cam2world.{c}": gym.spaces.Box(-np.inf, np.inf, (4, 4), np.float32) for c in cameras},
                **privileged,
            }
        ),
    }
    goal_dim = sum(spec.goal.values())
    if goal_dim:
        spaces["environment_state"] = gym.spaces.Box(-np.inf, np.inf, (goal_dim,), np.float32)
    return gym.spaces.Dict(spaces)


class ObsBenchEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": CONTROL_FPS}

    def __init__(
        self,
        task: str,
        cameras=("base_camera",),
        image_size: int = 128,
        control_mode: str = DEFAULT_CONTROL_MODE,
        asset_dir: str | None = None,
        seed: int | None = None,
        episode_length: int | None = None,
        render_mode: str | None = "rgb_array",
        perturbation: str | None = None,
        device: str | None = None,
        num_envs: int = 1,
        sim_backend: str | None = None,
    ):
        spec = task_spec(task)
        # SAPIEN renders on the GPU of `device` (cuda, cuda:N), else on the CPU; asked for explicitly, so a
        # CPU-only machine gets no "CUDA not found, falling back" warning.
        self.render_backend = render_backend(device)
        self.num_envs, self.sim_backend = num_envs, check_sim_backend(sim_backend, num_envs, self.render_backend)
        check_env_options(control_mode, image_size)
        import_task(spec, asset_dir)
        self.spec_ = spec
        self.cameras = list(cameras)
        self.image_size = image_size
        self.render_mode = render_mode
        self.task = spec.description
        self.task_description = spec.description
        self._next_seed = seed
        self.perturbation = check_perturbation(parse_perturbation(perturbation), num_envs)
        check_supported(self.perturbation, MANISKILL_KINDS, "ManiSkill")
        configs = task_sensor_configs(spec, image_size)
        if self.perturbation and self.perturbation.kind == "noise":
            use_ray_tracing(int(self.perturbation.scalar), configs)
        max_steps = episode_length or spec.max_steps
        self._make(control_mode, configs, max_steps)
        if self.perturbation and self.perturbation.kind.startswith("camera"):
            self._move_cameras(control_mode, configs, max_steps)
        if self.perturbation and self.perturbation.kind in ("light", "background"):
            apply_scene_perturbation(self._env.unwrapped, self.perturbation)
        self.unwrapped_ms = self._env.unwrapped
        self.device = self.unwrapped_ms.device  # where reset_all / step_all keep their tensors
        noisy = self.perturbation is not None and self.perturbation.kind == "depth_noise"
        self._depth_noise = DepthNoiser(self.perturbation, num_envs, self.device) if noisy else None
        self.action_space = gym.spaces.Box(-1.0, 1.0, self.unwrapped_ms.single_action_space.shape, np.float32)
        self.observation_space = observation_space(spec, self.cameras, image_size)
        self._milestones: dict[str, bool] = {}
        self._episode_start: dict = {}  # the task's `episode_start` of the running episodes

    def _move_cameras(self, control_mode: str, sensor_configs: dict, max_steps: int) -> None:
        """Rebuild the env with its cameras moved by the camera perturbation: a camera's look-at point is known only
        once ManiSkill has built it, and sensors are fixed when the env is made, so the first env is replaced."""
        moved = camera_overrides(self._env.unwrapped, self.cameras, self.perturbation, self.spec_.camera)
        for cam, config in moved.items():
            sensor_configs[cam] = {**sensor_configs.get(cam, {}), **config}
        self._env.close()
        self._make(control_mode, sensor_configs, max_steps)

    def _make(self, control_mode: str, sensor_configs: dict, max_steps: int) -> None:
        try:
            self._env = gym.make(
                self.spec_.env_id,
                obs_mode="rgb+depth" if self.cameras else "state_dict",  # a policy that reads no camera renders none
                control_mode=control_mode,
                render_mode="rgb_array",
                sensor_configs=sensor_configs,
                num_envs=self.num_envs,
                max_episode_steps=max_steps,
                sim_backend=self.sim_backend,
                render_backend=self.render_backend,
            )
            self._env.reset(seed=0)
            if self.cameras:  # before any is taken off, so the refusal lists every camera the task has
                check_cameras(self.spec_, self.cameras, list(self._env.unwrapped._sensors))
            self._drop_unread_cameras()
        except Exception as err:
            if self.sim_backend == "physx_cuda" and not physx_gpu_library().is_file():
                raise GpuSimulationError(
                    f"ManiSkill's GPU simulation needs SAPIEN's GPU PhysX library at {physx_gpu_library()}, which "
                    f"SAPIEN downloads from GitHub at its first GPU simulation; that failed ({type(err).__name__}: "
                    f"{err}). Run once where GitHub is reachable and copy the file here (the device check's bundle "
                    "carries it: scripts/device_bundle.py), or evaluate on ManiSkill's CPU simulation: "
                    "--eval.sim_backend=physx_cpu."
                ) from err
            if isinstance(err, RuntimeError) and any(w in str(err).lower() for w in ("vulkan", "vk::", "render")):
                raise RenderingError(f"{RENDERING_HELP} (SAPIEN: {err})") from err
            raise

    def _drop_unread_cameras(self) -> bool:
        """Take the cameras no observation reads off the scene: ManiSkill stops rendering them, and a camera the
        robot carries (the wrist camera of StackCube and PegInsertionSide) is no longer drawn in the other cameras'
        views or the videos, since its detailed mesh costs more to draw on a CPU renderer than the rest of the scene
        (its mass and collision box stay). ManiSkill rebuilds its sensors when it rebuilds the scene (PegInsertionSide
        at every reset), so this runs after every reset; returns whether it took any off, that is whether the
        observation ManiSkill returned still has them. Under GPU simulation, which cannot hide a body, the mesh stays
        drawn."""
        ms_env = self._env.unwrapped
        sensors = ms_env._sensors  # the same dict as its scene's `sensors`, which rendering walks
        # with no camera read, nothing renders (the env observes state only): its sensors are left alone
        unread = [name for name in sensors if name not in self.cameras] if self.cameras else []
        if not unread:  # every reset but a scene rebuild's
            return False
        import sapien

        for name in unread:
            sensor = sensors.pop(name)
            if name not in ms_env._agent_sensor_configs or ms_env.scene.gpu_sim_enabled:
                continue
            for link in sensor.config.mount._objs:  # the robot link the camera is mounted on
                body = link.entity.find_component_by_type(sapien.render.RenderBodyComponent)
                if body is not None:
                    body.visibility = 0
        return True

    # ---- observation conversion --------------------------------------------------------------------------

    def schema_frames(self, obs: dict) -> dict:
        """ManiSkill observation -> dataset schema keys (lerobot_obsbench/schema.py), batched over the envs:
        tensors (num_envs, ...) on the simulator's device."""
        import torch

        frames = {}
        for cam in self.cameras:
            data, param = obs["sensor_data"][cam], obs["sensor_param"][cam]
            frames[image_key(cam)] = data["rgb"].to(torch.uint8)
            frames[depth_key(cam)] = data["depth"].clamp_min(0).to(torch.uint16)
            frames[intrinsics_key(cam)] = opencv_intrinsics(param["intrinsic_cv"])
            frames[cam2world_key(cam)] = cam2world_from_extrinsic(param["extrinsic_cv"])
        frames[STATE_KEY] = torch.cat([obs["agent"]["qpos"], obs["extra"]["tcp_pose"]], dim=1).float()
        if self.spec_.privileged_actors:
            frames[PRIVILEGED_STATE_KEY] = self.spec_.privileged_state(self.unwrapped_ms)
        if self.spec_.goal:
            goal = [obs["extra"][k].reshape(self.num_envs, -1) for k in self.spec_.goal]
            frames[ENV_STATE_KEY] = torch.cat(goal, dim=1).float()
        if self._depth_noise is not None:
            self._depth_noise.apply(frames, self.cameras)
        return frames

    def schema_frame(self, obs: dict) -> dict[str, np.ndarray]:
        """The first env's frame of `schema_frames`, as NumPy arrays (what datasets record)."""
        return {key: to_numpy(value[0]) for key, value in self.schema_frames(obs).items()}

    to_env_observation = staticmethod(frame_to_env_observation)

    # ---- all envs at once: tensors (num_envs, ...) on the simulator's device -----------------------------------

    def _infos(self, info: dict, stepped: bool = True) -> dict:
        """The step's success and the milestones achieved at any step so far (none at a reset: until the
        simulation steps, ManiSkill still reports the previous episode's contacts, a grasp among them)."""
        import torch

        no = torch.zeros(self.num_envs, dtype=torch.bool, device=self.unwrapped_ms.device)
        success = info["success"].reshape(-1).bool() if "success" in info else no
        for name in self.spec_.sub_success:
            now = self.spec_.milestone(name, self.unwrapped_ms, info, success, self._episode_start) if stepped else no
            self._milestones[name] = now | self._milestones[name] if name in self._milestones else now
        return {"is_success": success, **{f"sub_success/{k}": v for k, v in self._milestones.items()}}

    def reset_all(self, seeds=None, options: dict | None = None) -> tuple[dict, dict]:
        """Reset every env, env i with `seeds[i]` (None: unseeded); the batched env observation and info."""
        seed = None if seeds is None else [int(s) for s in seeds]
        if seed is not None and len(seed) != self.num_envs:
            raise ConfigError(f"reset_all needs one seed per env ({self.num_envs}); got {len(seed)}")
        obs, info = self._env.reset(seed=seed, options=options)
        if self._depth_noise is not None:
            self._depth_noise.reset(seed or [None] * self.num_envs)
        rebuilt = self._drop_unread_cameras()  # ManiSkill's observation drew the cameras it rebuilt
        if self.spec_.initialize(self.unwrapped_ms) or rebuilt:
            obs = self.unwrapped_ms.get_obs()
        self._milestones = {}
        self._episode_start = self.spec_.episode_start(self.unwrapped_ms)
        return self.to_env_observation(self.schema_frames(obs)), self._infos(info, stepped=False)

    def step_all(self, actions) -> tuple:
        """Step every env with its row of `actions` (num_envs, A): batched observation, reward, terminated,
        truncated (num_envs,) and info."""
        obs, reward, terminated, truncated, info = self._env.step(actions)
        return (
            self.to_env_observation(self.schema_frames(obs)),
            reward.reshape(-1),
            terminated.reshape(-1),
            truncated.reshape(-1),
            self._infos(info),
        )

    def render_all(self):
        """Every env's viewer image, (num_envs, H, W, 3) uint8 on the renderer's device."""
        return self._env.render()

    # ---- gym API: one env ----------------------------------------------------------------------------------

    def _first_env(self, value):
        if self.num_envs != 1:
            raise BatchedEnvError(f"this ObsBenchEnv holds {self.num_envs} envs: use reset_all / step_all / render_all")
        if isinstance(value, dict):
            return {key: self._first_env(v) for key, v in value.items()}
        return to_numpy(value[0])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is None and self._next_seed is not None:
            seed, self._next_seed = self._next_seed, self._next_seed + 1
        obs, info = self.reset_all(None if seed is None else [seed], options)
        return self._first_env(obs), {key: bool(v) for key, v in self._first_env(info).items()}

    def step(self, action):
        actions = np.asarray(action, dtype=np.float32)[None]
        obs, reward, terminated, truncated, info = self.step_all(actions)
        return (
            self._first_env(obs),
            float(self._first_env(reward)),
            bool(self._first_env(terminated)),
            bool(self._first_env(truncated)),
            {key: bool(v) for key, v in self._first_env(info).items()},
        )

    def raw_observation(self) -> dict:
        """The current ManiSkill observation (batch of 1), e.g. to record a frame after reset/step."""
        return self.unwrapped_ms.get_obs()

    def render(self):
        return self._first_env(self.render_all())

    def close(self):
        self._env.close()


def make_obsbench_env(task: str, **kwargs) -> ObsBenchEnv:
    return ObsBenchEnv(task, **kwargs)
