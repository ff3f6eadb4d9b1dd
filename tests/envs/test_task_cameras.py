"""Each task of the cpu-suite and cpu-ranking grids sees its objects: at every episode start over the 25 test seeds
the grids evaluate, the objects lie in the task's point-cloud crop box and show enough pixels in its camera's 64²
frame; and a camera no policy reads is taken off the scene. Needs the simulator (scripts/setup_system.sh): marked
slow."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_obsbench.bench.diagnostics import object_positions, pixel_diameters
from lerobot_obsbench.bench.grid import load_grid
from lerobot_obsbench.envs.base_task import TASKS, eval_seeds, missing_assets, task_spec
from lerobot_obsbench.envs.maniskill import ObsBenchEnv
from lerobot_obsbench.envs.perturbations import capture_look_at

pytestmark = pytest.mark.slow

SUITE = sorted({*load_grid("cpu-suite").tasks, *load_grid("cpu-ranking").tasks})
SIZE = 64
EPISODES = 25  # the grids' eval_episodes
# at least a 3x3 patch of each object in the frame, and a bounding sphere at least 4 pixels across
MIN_PIXELS = 9
MIN_DIAMETER = 4.0


def _in_frame(centre, K, cam2world) -> bool:
    """Whether the world point `centre` projects into the camera's SIZE² frame, in front of it."""
    x, y, z = (np.linalg.inv(cam2world) @ np.append(centre, 1.0))[:3]
    u, v = K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2]
    return bool(z > 0 and 0 <= u <= SIZE and 0 <= v <= SIZE)


def _object_pixels(env: ObsBenchEnv, actor) -> int:
    """Pixels of `actor` in the base camera's current frame (ManiSkill's per-actor segmentation)."""
    camera = env.unwrapped_ms._sensors["base_camera"]
    env.unwrapped_ms.scene.update_render()
    camera.capture()
    segmentation = camera.get_obs(rgb=False, depth=False, position=False, segmentation=True)["segmentation"]
    return int(np.isin(segmentation[0, ..., 0].cpu().numpy(), actor.per_scene_id.cpu().numpy()).sum())


@pytest.mark.parametrize("task", SUITE)
def test_objects_lie_in_the_crop_box_and_fill_pixels_at_every_start(task):
    spec = task_spec(task)
    assert spec.objects and spec.workspace is not None, f"{task}: a suite task names its objects and crop box"
    lo, hi = np.array(spec.workspace[0::2]), np.array(spec.workspace[1::2])
    env = ObsBenchEnv(task, image_size=SIZE)
    pixels = {name: [] for name in spec.objects}
    try:
        for seed in eval_seeds(EPISODES):
            env.reset(seed=seed)
            frame = env.schema_frame(env.unwrapped_ms.get_obs())
            privileged = frame["observation.privileged_state"][None]
            K, cam2world = frame["observation.intrinsics.base_camera"], frame["observation.cam2world.base_camera"]
            for name, (centre, radius) in object_positions(privileged, spec.privileged_actors, spec.objects).items():
                centre = centre[0]
                # the whole bounding sphere across the table, its centre within the box's heights
                assert np.all(centre[:2] - radius >= lo[:2]) and np.all(centre[:2] + radius <= hi[:2]), (
                    f"{task} seed {seed}: {name} at {centre.round(3)} (radius {radius}) leaves {spec.workspace}"
                )
                assert lo[2] <= centre[2] <= hi[2], f"{task} seed {seed}: {name} at height {centre[2]:.3f}"
                assert _in_frame(centre, K, cam2world), f"{task} seed {seed}: {name}'s centre is out of the frame"
                diameter = pixel_diameters(centre[None], radius, K[None], cam2world[None])[0]
                assert diameter >= MIN_DIAMETER, f"{task} seed {seed}: {name} spans {diameter:.1f} px"
                pixels[name].append(_object_pixels(env, getattr(env.unwrapped_ms, name)))
    finally:
        env.close()
    for name, counts in pixels.items():
        assert min(counts) >= MIN_PIXELS, f"{task}: {name} shows {min(counts)} pixels at some start (of {counts})"


@pytest.mark.parametrize("task", ["StackCube-v1", "PegInsertionSide-v1"])
def test_unread_wrist_camera_is_neither_rendered_nor_drawn(task):
    import sapien

    def mesh_visibility(env):
        link = env.unwrapped_ms.agent.robot.links_map["camera_link"]
        return [part.entity.find_component_by_type(sapien.render.RenderBodyComponent).visibility for part in link._objs]

    base_only = ObsBenchEnv(task, image_size=SIZE)
    both = ObsBenchEnv(task, image_size=SIZE, cameras=("base_camera", "hand_camera"))
    try:
        for seed in (0, 1):
            obs, _ = base_only.reset(seed=seed)
            both_obs, _ = both.reset(seed=seed)
            assert set(obs["pixels"]) == {"base_camera"} and set(both_obs["pixels"]) == {"base_camera", "hand_camera"}
            assert list(base_only.unwrapped_ms._sensors) == ["base_camera"]
            assert mesh_visibility(base_only) == [0.0]
            assert sorted(both.unwrapped_ms._sensors) == ["base_camera", "hand_camera"]
            assert mesh_visibility(both) == [1.0]
            # the frame a reset returns is drawn as every later one (PegInsertionSide rebuilds its scene, and with
            # it the cameras, at every reset)
            again = base_only.schema_frame(base_only.unwrapped_ms.get_obs())
            np.testing.assert_array_equal(obs["pixels"]["base_camera"], again["observation.images.base_camera"])
            # the same scene, state for state: only the wrist camera's drawing differs
            np.testing.assert_array_equal(
                again["observation.privileged_state"],
                both.schema_frame(both.unwrapped_ms.get_obs())["observation.privileged_state"],
            )
            obs, *_ = base_only.step(np.zeros(base_only.action_space.shape, np.float32))
            assert set(obs["pixels"]) == {"base_camera"}
    finally:
        base_only.close()
        both.close()


def test_a_camera_move_moves_the_scene_camera_and_leaves_the_wrist_camera_on_the_hand():
    """camera_yaw with both of StackCube's cameras: the base camera orbits; the wrist camera, which has no
    look-at point in the scene, keeps its pose on the hand."""
    still = ObsBenchEnv("StackCube-v1", image_size=SIZE, cameras=("base_camera", "hand_camera"))
    moved = ObsBenchEnv(
        "StackCube-v1", image_size=SIZE, cameras=("base_camera", "hand_camera"), perturbation="camera_yaw:10"
    )
    try:
        poses = []
        for env in (still, moved):
            obs, _ = env.reset(seed=0)
            poses.append({cam: obs["robot_state"][f"cam2world.{cam}"] for cam in ("base_camera", "hand_camera")})
        assert not np.allclose(poses[0]["base_camera"], poses[1]["base_camera"], atol=1e-3)
        np.testing.assert_allclose(poses[0]["hand_camera"], poses[1]["hand_camera"], atol=1e-6)
    finally:
        still.close()
        moved.close()


# a task whose ManiSkill assets are downloaded at first use (TurnFaucet's) cannot be built on an offline machine
BUILDABLE = sorted(task for task in TASKS if not missing_assets(task_spec(task)))


@pytest.mark.parametrize("task", BUILDABLE)
def test_every_tasks_scene_cameras_have_the_look_at_point_a_camera_move_orbits_about(task):
    """A camera move orbits each scene camera about the point its ManiSkill config looks at, read by instrumenting
    `look_at` (`capture_look_at`): found for every default camera of every task, whichever way its env imported
    `look_at` (PullCube by name), and the built camera's optical axis points from that eye to that target."""
    env = ObsBenchEnv(task, image_size=SIZE)
    try:
        ms_env = env.unwrapped_ms
        looks = capture_look_at(ms_env)
        configs = ms_env._default_sensor_configs
        assert set(looks) == {c.uid for c in (configs if isinstance(configs, (list, tuple)) else [configs])}
        for config in configs if isinstance(configs, (list, tuple)) else [configs]:
            eye, target = looks[config.uid]
            matrix = np.asarray(config.pose.to_transformation_matrix(), dtype=np.float64).reshape(-1, 4, 4)[0]
            np.testing.assert_allclose(matrix[:3, 3], eye, atol=1e-5)
            # SAPIEN's camera looks along its x axis
            np.testing.assert_allclose(matrix[:3, 0], (target - eye) / np.linalg.norm(target - eye), atol=1e-4)
    finally:
        env.close()
