"""`MetaWorldEnv`: a Meta-World task emitting the plugin's sensor schema (lerobot_obsbench/schema.py), so every
observation space trains and evaluates on it as on a ManiSkill task.

- colour: MuJoCo's renderer at the policy's size (`image_size`, square);
- depth: MuJoCo's depth buffer in metres along the optical axis (`mujoco.Renderer` linearises it exactly from the
  model's clipping planes, near = znear x extent and far = zfar x extent), stored as uint16 millimetres; what lies
  beyond `DEPTH_LIMIT` (the sky at the far plane) is 0, invalid;
- intrinsics: OpenCV's K from the camera's vertical field of view (square pixels, the principal point at the image
  centre: (W - 1) / 2 in OpenCV's pixel-centre coordinates);
- cam2world: the camera's pose in the simulation, OpenCV's axes (MuJoCo's camera looks along -z with y up, OpenCV's
  along +z with y down), turned half a turn about the optical axis for the cameras whose image is turned
  (`TURNED_CAMERAS`, as LeRobot shows them);
- state: the Sawyer's 7 arm joints and 2 finger joints, then the hand's position and orientation (quaternion wxyz):
  16 values, the end-effector pose last as the schema asks;
- privileged state (the oracle's input): Meta-World's two object slots as its observation gives them (position and
  quaternion each, the second zeros where the task has one object; its tasks differ in quaternion convention, and
  the oracle reads one task's at a time), then the goal's position with the identity rotation.

Colour keeps the scene's lighting and shadows, from a smaller shadow map (`SHADOW_MAP_SIZE`). Only what the policy
reads is rendered: `cameras` (none for the blind and oracle controls) and, of each, the `sensors` it reads (colour,
depth, or both). `reset(seed=s)` places the objects from `s` alone (Meta-World's seeded randomisation, as LeRobot's
env sets it), so an episode is reproducible from its seed. `perturbation` (`kind:value`, envs/perturbations.py;
Meta-World takes every kind but ray tracing) changes the scene's cameras, lights or background
(envs/metaworld/perturbations.py) or, `depth_noise`, its depth images, the noise drawn from the episode's seed. An
episode ends at success (`terminated`, as in LeRobot's env) or after `episode_length` steps (`truncated`).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from lerobot_obsbench.envs.base_task import check_cameras
from lerobot_obsbench.envs.metaworld.perturbations import apply_perturbation
from lerobot_obsbench.envs.metaworld.rendering import check_gl, open_renderer
from lerobot_obsbench.envs.metaworld.tasks import (
    CORNER2_POSITION,
    MAX_STEPS,
    TURNED_CAMERAS,
    metaworld_task,
)
from lerobot_obsbench.envs.perturbations import METAWORLD_KINDS, DepthNoiser, check_supported, parse_perturbation
from lerobot_obsbench.errors import ConfigError, MissingDependencyError
from lerobot_obsbench.schema import (
    DEFAULT_POINT_FEATURES,
    DEPTH_PREFIX,
    IMAGE_PREFIX,
    MIN_IMAGE_SIZE,
    POSE_SIZE,
    PRIVILEGED_STATE_KEY,
    STATE_KEY,
    cam2world_key,
    depth_key,
    frame_to_env_observation,
    image_key,
    intrinsics_key,
    privileged_state_names,
    read_sensors,
)

ARM_JOINTS = tuple(f"right_j{i}" for i in range(7))
FINGER_JOINTS = ("r_close", "l_close")
HAND_BODY = "hand"
STATE_SIZE = len(ARM_JOINTS) + len(FINGER_JOINTS) + POSE_SIZE
ACTION_SIZE = 4  # the hand's displacement (x, y, z) and the gripper's effort, each in [-1, 1]
DEPTH_LIMIT = 10.0  # metres: farther is no surface of the scene (the sky, the far plane) and is stored as 0
OBJECT_SLOTS = slice(4, 18)  # Meta-World's observation: hand (3), gripper (1), then two objects' poses (7 each)
INSTALL_HELP = "pip install 'lerobot_policy_obsbench[metaworld]' (metaworld 3.0.0, LeRobot's pin, with mujoco 3.3.7)"


def opencv_intrinsics(fovy_degrees: float, size: int) -> np.ndarray:
    """K (3, 3) of a square `size` x `size` image from MuJoCo's vertical field of view."""
    focal = size / 2 / np.tan(np.radians(fovy_degrees) / 2)
    centre = (size - 1) / 2
    return np.array([[focal, 0, centre], [0, focal, centre], [0, 0, 1]], dtype=np.float32)


def opencv_cam2world(position: np.ndarray, mujoco_rotation: np.ndarray, turned: bool) -> np.ndarray:
    """OpenCV camera -> world (4, 4) from a MuJoCo camera's world position and rotation (columns: its x, y, z axes
    in the world; it looks along -z with y up); `turned`: the image is turned half a turn."""
    axes = np.diag([-1.0, 1.0, -1.0]) if turned else np.diag([1.0, -1.0, -1.0])
    pose = np.eye(4, dtype=np.float32)
    pose[:3, :3] = mujoco_rotation.reshape(3, 3) @ axes
    pose[:3, 3] = position
    return pose


def _turned(image: np.ndarray, camera: str) -> np.ndarray:
    """`image` as the camera shows it: turned half a turn for `TURNED_CAMERAS`."""
    return np.ascontiguousarray(image[::-1, ::-1]) if camera in TURNED_CAMERAS else image


def rendered_sensors(obs_space: str, point_features: str = DEFAULT_POINT_FEATURES) -> tuple[str, ...]:
    """What the env renders for a policy on `obs_space` whose points carry `point_features` (`sensors`): of colour
    and depth, those the policy reads (`read_sensors`)."""
    read = read_sensors(obs_space, point_features)
    return tuple(prefix for prefix in (IMAGE_PREFIX, DEPTH_PREFIX) if prefix in read)


def _import_metaworld():
    try:
        import metaworld
    except ImportError as err:
        raise MissingDependencyError(f"Meta-World tasks need Meta-World ({err}): {INSTALL_HELP}") from None
    return metaworld


# MuJoCo's shadow map (pixels a side; the scene's default is 4096): a quarter of the side renders the same lighting
# and shadows with softer edges, far cheaper on a CPU renderer (measured: docs/metaworld.md#cost).
SHADOW_MAP_SIZE = 1024


class MetaWorldEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 80}

    def __init__(
        self,
        task: str,
        cameras=("corner2",),
        image_size: int = 128,
        sensors: tuple[str, ...] = (IMAGE_PREFIX, DEPTH_PREFIX),
        episode_length: int | None = None,
        render_mode: str | None = "rgb_array",
        perturbation: str | None = None,
    ):
        self.spec_ = metaworld_task(task)
        self.cameras = list(cameras)
        check_cameras(self.spec_, self.cameras)
        self.perturbation = parse_perturbation(perturbation)
        check_supported(self.perturbation, METAWORLD_KINDS, "Meta-World")
        if not isinstance(image_size, int) or isinstance(image_size, bool) or image_size < MIN_IMAGE_SIZE:
            raise ConfigError(f"image_size must be a whole number of pixels >= {MIN_IMAGE_SIZE}; got {image_size!r}")
        unknown = [s for s in sensors if s not in (IMAGE_PREFIX, DEPTH_PREFIX)]
        if unknown:
            raise ConfigError(f"sensors are {IMAGE_PREFIX!r} and/or {DEPTH_PREFIX!r}; got {unknown}")
        self.image_size, self.sensors = image_size, tuple(sensors)
        self.max_steps = episode_length or MAX_STEPS
        self.render_mode = render_mode
        self.task = self.task_description = self.spec_.description
        if self.cameras:
            check_gl()  # before Meta-World builds its simulation
        metaworld = _import_metaworld()
        benchmark = metaworld.MT1(self.spec_.name, seed=42)  # one task, its first train variant, as LeRobot's env
        self._env = benchmark.train_classes[self.spec_.name]()
        self._env.set_task(benchmark.train_tasks[0])
        self._env.max_path_length = self.max_steps  # Meta-World refuses a step past its own budget (500)
        self._env.model.cam_pos[self._env.model.camera("corner2").id] = CORNER2_POSITION
        self._env.reset()
        self._env._freeze_rand_vec = False  # a new placement at each reset, drawn from the reset's seed
        self._env.seeded_rand_vec = True
        apply_perturbation(self._env.model, self._env.data, self.cameras, self.perturbation)
        noisy = self.perturbation is not None and self.perturbation.kind == "depth_noise"
        self._depth_noise = DepthNoiser(self.perturbation) if noisy else None
        self.objects = self.spec_.privileged_actors
        self._renderer = None
        if self.cameras:
            self._env.model.vis.quality.shadowsize = SHADOW_MAP_SIZE
            self._renderer = open_renderer(self._env.model, image_size, image_size)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (ACTION_SIZE,), np.float32)
        self.observation_space = self._observation_space()
        self._steps = 0
        self._last_obs = None

    # ---- what the env observes ---------------------------------------------------------------------------------

    @property
    def privileged_state_names(self) -> list[str]:
        return privileged_state_names(self.objects)

    def _observation_space(self) -> gym.spaces.Dict:
        size = (self.image_size, self.image_size)
        box = gym.spaces.Box
        return gym.spaces.Dict(
            {
                "pixels": gym.spaces.Dict(
                    {c: box(0, 255, (*size, 3), np.uint8) for c in self.cameras if IMAGE_PREFIX in self.sensors}
                ),
                "agent_pos": box(-np.inf, np.inf, (STATE_SIZE,), np.float32),
                "robot_state": gym.spaces.Dict(
                    {
                        **{
                            f"depth.{c}": box(0, 65535, (*size, 1), np.uint16)
                            for c in self.cameras
                            if DEPTH_PREFIX in self.sensors
                        },
                        **{f"intrinsics.{c}": box(-np.inf, np.inf, (3, 3), np.float32) for c in self.cameras},
                        **{f"cam2world.{c}": box(-np.inf, np.inf, (4, 4), np.float32) for c in self.cameras},
                        "privileged_state": box(-np.inf, np.inf, (len(self.objects) * POSE_SIZE,), np.float32),
                    }
                ),
            }
        )

    def camera_calibration(self, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """(K, cam2world) of `camera` now (a camera the robot carries moves with it)."""
        model, data = self._env.model, self._env.data
        index = model.camera(camera).id
        intrinsics = opencv_intrinsics(float(model.cam_fovy[index]), self.image_size)
        return intrinsics, opencv_cam2world(data.cam_xpos[index], data.cam_xmat[index], camera in TURNED_CAMERAS)

    def _render(self, camera: str, colour: bool, depth: bool) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(colour (H, W, 3) uint8, depth (H, W, 1) uint16 mm) of `camera`, each None where not asked for."""
        renderer = self._renderer
        renderer.update_scene(self._env.data, camera=camera)
        image = millimetres = None
        if colour:
            image = _turned(renderer.render(), camera)
        if depth:
            renderer.enable_depth_rendering()
            metres = renderer.render()
            renderer.disable_depth_rendering()
            millimetres = _turned(np.where(metres < DEPTH_LIMIT, np.round(metres * 1000), 0), camera)
            millimetres = millimetres.astype(np.uint16)[..., None]
        return image, millimetres

    def segmentation(self, camera: str) -> np.ndarray:
        """(H, W) int32: the MuJoCo geom each pixel of `camera` shows, -1 where none (the sky)."""
        import mujoco

        renderer = self._renderer
        renderer.update_scene(self._env.data, camera=camera)
        renderer.enable_segmentation_rendering()
        ids = renderer.render()
        renderer.disable_segmentation_rendering()
        geom = np.where(ids[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, ids[..., 0], -1)
        return _turned(geom, camera).astype(np.int32)

    def _state(self) -> np.ndarray:
        model, data = self._env.model, self._env.data
        joints = [data.qpos[model.joint(name).qposadr[0]] for name in (*ARM_JOINTS, *FINGER_JOINTS)]
        hand = data.body(HAND_BODY)
        return np.concatenate([joints, hand.xpos, hand.xquat]).astype(np.float32)

    def _privileged_state(self, obs: np.ndarray) -> np.ndarray:
        goal = np.concatenate([self._env._target_pos, [1.0, 0.0, 0.0, 0.0]])
        return np.concatenate([obs[OBJECT_SLOTS], goal]).astype(np.float32)

    @property
    def metaworld_observation(self) -> np.ndarray:
        """Meta-World's own last observation (39 values), which its scripted experts read."""
        return self._last_obs

    def schema_frame(self) -> dict[str, np.ndarray]:
        """The current frame in the schema's keys (what datasets record)."""
        frame = {}
        for camera in self.cameras:
            colour, depth = self._render(camera, IMAGE_PREFIX in self.sensors, DEPTH_PREFIX in self.sensors)
            if colour is not None:
                frame[image_key(camera)] = colour
            if depth is not None:
                frame[depth_key(camera)] = depth
            frame[intrinsics_key(camera)], frame[cam2world_key(camera)] = self.camera_calibration(camera)
        if self._depth_noise is not None and DEPTH_PREFIX in self.sensors:
            batch = {key: frame[key][None] for key in frame}
            frame.update({key: value[0] for key, value in self._depth_noise.apply(batch, self.cameras).items()})
        frame[STATE_KEY] = self._state()
        frame[PRIVILEGED_STATE_KEY] = self._privileged_state(self._last_obs)
        return frame

    # ---- gym ---------------------------------------------------------------------------------------------------

    def reset(self, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._env.seed(seed)  # Meta-World's reset ignores its seed argument
        if self._depth_noise is not None:
            self._depth_noise.reset([seed])
        self._last_obs, _ = self._env.reset()
        self._steps = 0
        return frame_to_env_observation(self.schema_frame()), {"is_success": False}

    def step(self, action):
        action = np.clip(np.asarray(action, dtype=np.float32).reshape(ACTION_SIZE), -1.0, 1.0)
        self._last_obs, reward, _, _, info = self._env.step(action)
        self._steps += 1
        success = bool(info.get("success", 0.0))
        truncated = not success and self._steps >= self.max_steps
        info = {"is_success": success, **{k: float(v) for k, v in info.items() if np.isscalar(v)}}
        return frame_to_env_observation(self.schema_frame()), float(reward), success, truncated, info

    def render(self):
        """The first camera's colour (none with no camera)."""
        if not self.cameras:
            return None
        colour, _ = self._render(self.cameras[0], colour=True, depth=False)
        return colour

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._env.close()
