"""Meta-World tasks as OBSBench tasks: LeRobot's task list, the sensor schema's geometry on MuJoCo's frames (every
camera's cloud on the model's true surfaces, in millimetres), seeded resets, the scripted expert, and the refusals
that come before anything slow."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from lerobot_obsbench import geometry, schema
from lerobot_obsbench.envs.base_task import TaskError
from lerobot_obsbench.envs.metaworld.configuration import MetaWorldEnvConfig
from lerobot_obsbench.envs.metaworld.env import SHADOW_MAP_SIZE, STATE_SIZE, MetaWorldEnv, rendered_sensors
from lerobot_obsbench.envs.metaworld.rendering import choose_gl
from lerobot_obsbench.envs.metaworld.tasks import CAMERAS, metaworld_task, metaworld_tasks, tasks_of
from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.schema import SchemaError
from tests.support.paths import REPO_ROOT

TASK = "drawer-open-v3"


def test_the_task_list_is_lerobots_with_dp3s_groups():
    import json
    from importlib import resources

    lerobot = json.loads(resources.files("lerobot.envs").joinpath("metaworld_config.json").read_text())
    assert list(metaworld_tasks()) == list(lerobot["TASK_DESCRIPTIONS"])
    assert tasks_of("easy") == lerobot["DIFFICULTY_TO_TASKS"]["easy"]
    assert metaworld_task("metaworld-drawer-open-v3").expert == "SawyerDrawerOpenV3Policy"


def test_an_unknown_task_or_camera_or_another_control_mode_is_refused_before_anything_slow():
    with pytest.raises(TaskError, match=r"unknown Meta-World task 'drawer-opn-v3'; did you mean drawer-open-v3"):
        metaworld_task("drawer-opn-v3")
    started = time.perf_counter()
    with pytest.raises(TaskError, match=r"cameras \['wrist'\]: drawer-open-v3 has no such camera; its cameras are"):
        MetaWorldEnv(TASK, cameras=["wrist"])
    assert time.perf_counter() - started < 1  # refused before Meta-World builds its simulation
    # lerobot-eval's env config: refused when parsed, before the policy loads
    with pytest.raises(TaskError, match=r"did you mean drawer-open-v3"):
        MetaWorldEnvConfig(task="drawer-opn-v3")
    with pytest.raises(TaskError, match=r"drawer-open-v3 has no such camera"):
        MetaWorldEnvConfig(task=TASK, cameras=["wrist"])
    with pytest.raises(SchemaError, match=r"Unknown obs_space 'pointclod'; choose one of"):
        MetaWorldEnvConfig(task=TASK, obs_space="pointclod")
    with pytest.raises(ConfigError, match=r"--env.point_features=xyz is read with --env.obs_space only"):
        MetaWorldEnvConfig(task=TASK, point_features="xyz")
    # ManiSkill's controllers are refused for the one Meta-World acts by, before the policy loads
    from lerobot_obsbench.envs.evaluate import evaluate
    from lerobot_obsbench.errors import UsageError

    with pytest.raises(UsageError, match="Meta-World tasks act by mocap_delta_pos only; got --env.control_mode pd_"):
        evaluate("no/such/checkpoint", TASK, 1, control_mode="pd_joint_delta_pos")


def _refusal(environment: dict) -> subprocess.CompletedProcess:
    code = f"from lerobot_obsbench.envs.metaworld.env import MetaWorldEnv; MetaWorldEnv({TASK!r})"
    return subprocess.run(
        [sys.executable, "-c", code], env=environment, cwd=REPO_ROOT, capture_output=True, text=True, timeout=120
    )


def test_no_headless_gl_is_one_line_naming_what_to_install():
    """EGL with no vendor library to load (what a machine without Mesa's EGL has), and a back-end MuJoCo lacks."""
    no_egl = {**os.environ, "MUJOCO_GL": "egl", "__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent/egl_vendor.json"}
    result = _refusal(no_egl)
    assert result.returncode != 0
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("lerobot_obsbench.envs.metaworld.rendering.HeadlessGLError: MuJoCo could not open")
    assert "libegl-mesa0" in last and "MUJOCO_GL=osmesa" in last
    result = _refusal({**os.environ, "MUJOCO_GL": "wgl"})
    assert "HeadlessGLError: MUJOCO_GL='wgl' is not one of MuJoCo's back-ends" in result.stderr


def _surface_distance(model, data, geom: int, points: np.ndarray) -> np.ndarray:
    """Distance (m) of world points to a box or plane geom's surface (a box's signed-distance function)."""
    import mujoco

    local = (points - data.geom_xpos[geom]) @ data.geom_xmat[geom].reshape(3, 3)
    if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_PLANE:
        return np.abs(local[:, 2])
    outside = np.abs(local) - model.geom_size[geom]
    return np.abs(np.linalg.norm(np.maximum(outside, 0), axis=1) + np.minimum(outside.max(axis=1), 0))


@pytest.mark.parametrize("camera", CAMERAS)
def test_every_cameras_cloud_lies_on_the_models_surfaces(camera):
    """Depth + K + cam2world, unprojected by the plugin's geometry, put every pixel that shows a box or a plane
    (the table, its walls, the floor, the drawer's case...) on that geom's true surface: within the millimetre the
    uint16 depth is rounded to."""
    choose_gl()
    import mujoco
    import torch

    env = MetaWorldEnv(TASK, cameras=[camera], image_size=96)
    env.reset(seed=1)
    frame = env.schema_frame()
    shows = env.segmentation(camera)
    model, data = env._env.model, env._env.data

    depth = torch.from_numpy(frame[schema.depth_key(camera)][..., 0].astype(np.float32) / 1000)[None]
    intrinsics = torch.from_numpy(frame[schema.intrinsics_key(camera)])[None]
    cam2world = torch.from_numpy(frame[schema.cam2world_key(camera)])[None]
    world = geometry.transform_points(geometry.unproject_depth(depth, intrinsics), cam2world)[0].numpy()
    flat = (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_PLANE)
    measured = (depth[0].numpy() > 0) & (shows >= 0) & np.isin(model.geom_type[np.maximum(shows, 0)], flat)
    distances = np.concatenate(
        [_surface_distance(model, data, g, world[measured & (shows == g)]) for g in np.unique(shows[measured])]
    )
    env.close()
    millimetres = distances * 1000
    print(
        f"{camera}: {measured.sum()} points on {len(np.unique(shows[measured]))} boxes/planes, distance to the "
        f"surface median {np.median(millimetres):.3f} mm, p95 {np.percentile(millimetres, 95):.3f}, "
        f"max {millimetres.max():.3f}"
    )
    assert measured.sum() > 1000
    assert millimetres.max() < 1.0


def test_a_frame_has_the_schemas_keys_and_a_seed_places_the_objects():
    env = MetaWorldEnv(TASK, cameras=["corner2"], image_size=64)
    try:
        obs, info = env.reset(seed=7)
        frame = schema.env_observation_to_frame(obs)
        assert frame[schema.image_key("corner2")].shape == (64, 64, 3)
        assert frame[schema.depth_key("corner2")].dtype == np.uint16
        assert frame[schema.STATE_KEY].shape == (STATE_SIZE,)
        hand = env._env.data.body("hand").xpos
        np.testing.assert_allclose(frame[schema.STATE_KEY][-7:-4], hand, atol=1e-6)  # the EE pose last
        assert env.privileged_state_names[-7:] == [f"goal.{c}" for c in schema.POSE_COMPONENTS]
        assert frame[schema.PRIVILEGED_STATE_KEY].shape == (21,)
        first = frame[schema.PRIVILEGED_STATE_KEY]
        again = schema.env_observation_to_frame(env.reset(seed=7)[0])
        other = schema.env_observation_to_frame(env.reset(seed=8)[0])
        np.testing.assert_array_equal(again[schema.PRIVILEGED_STATE_KEY], first)
        np.testing.assert_array_equal(again[schema.depth_key("corner2")], frame[schema.depth_key("corner2")])
        assert not np.allclose(other[schema.PRIVILEGED_STATE_KEY], first)
    finally:
        env.close()


def test_the_env_renders_only_what_the_policy_reads():
    """Nothing for the controls, colour for images, depth for depth, both for a cloud with coloured points and
    depth alone for one of xyz points (DP3's); the frame then holds what was rendered, with its calibration."""
    colour, depth = schema.IMAGE_PREFIX, schema.DEPTH_PREFIX
    expected = {("none", "rgb+xyz"): (), ("state", "rgb+xyz"): (), ("rgb", "rgb+xyz"): (colour,)}
    expected |= {("depth", "rgb+xyz"): (depth,), ("pointcloud", "rgb+xyz"): (colour, depth)}
    expected |= {("pointcloud", "xyz"): (depth,), ("rgb+pointcloud", "xyz"): (colour, depth)}
    assert {key: rendered_sensors(*key) for key in expected} == expected
    env = MetaWorldEnv(TASK, cameras=["corner2"], image_size=32, sensors=rendered_sensors("pointcloud", "xyz"))
    try:
        frame = schema.env_observation_to_frame(env.reset(seed=0)[0])
    finally:
        env.close()
    assert schema.image_key("corner2") not in frame and frame[schema.depth_key("corner2")].shape == (32, 32, 1)
    assert schema.cam2world_key("corner2") in frame and schema.intrinsics_key("corner2") in frame
    # lerobot-eval's env config renders what the policy it is told of reads, and declares no colour it lacks
    config = MetaWorldEnvConfig(task=TASK, obs_space="pointcloud", point_features="xyz")
    assert config.gym_kwargs["sensors"] == (depth,) and "pixels/corner2" not in config.features
    assert MetaWorldEnvConfig(task=TASK).gym_kwargs["sensors"] == (colour, depth)


def test_colour_keeps_the_scenes_shadows_from_a_smaller_shadow_map():
    """The env's colour frames come from a 1024-pixel shadow map where the scene asks 4096: the same frame within a
    grey level on average, the shadows still there (the frame differs from one rendered without them)."""
    import mujoco

    from lerobot_obsbench.envs.metaworld.rendering import open_renderer

    env = MetaWorldEnv(TASK, cameras=["corner2"], image_size=64, sensors=(schema.IMAGE_PREFIX,))
    try:
        env.reset(seed=0)
        model, own = env._env.model, env._renderer
        assert model.vis.quality.shadowsize == SHADOW_MAP_SIZE < 4096
        frame = env._render("corner2", colour=True, depth=False)[0].astype(float)
        model.vis.quality.shadowsize = 4096
        env._renderer = open_renderer(model, 64, 64)
        scene_map = env._render("corner2", colour=True, depth=False)[0].astype(float)
        env._renderer.close()
        env._renderer = own
        own.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        unshadowed = env._render("corner2", colour=True, depth=False)[0].astype(float)
    finally:
        env.close()
    assert np.abs(frame - scene_map).mean() < 1.0
    assert np.abs(frame - unshadowed).mean() > 5 * np.abs(frame - scene_map).mean()


def test_each_tasks_crop_box_is_measured_from_its_experts_episodes():
    """workspaces.json holds a box for every task LeRobot lists, inside the table's box and from its surface up,
    and each task crops its own; measuring a task again over the file's seeds gives the box it holds."""
    import json

    from lerobot_obsbench.envs.metaworld.tasks import TABLE_WORKSPACE, WORKSPACES_FILE
    from lerobot_obsbench.envs.metaworld.workspaces import crop_box, task_positions

    stored = json.loads(WORKSPACES_FILE.read_text())
    assert set(stored["tasks"]) == set(metaworld_tasks())
    table = np.asarray(TABLE_WORKSPACE).reshape(3, 2)
    for name, box in stored["tasks"].items():
        bounds = np.asarray(box).reshape(3, 2)
        assert (bounds[:, 0] >= table[:, 0]).all() and (bounds[:, 1] <= table[:, 1]).all(), name
        assert (bounds[:, 1] - bounds[:, 0] >= 0.2).all() and bounds[2, 0] == table[2, 0], name
        assert metaworld_task(name).workspace == tuple(box)
    assert len({tuple(box) for box in stored["tasks"].values()}) > 10  # the tasks' boxes differ
    positions = task_positions("reach-v3", stored["episodes"])
    assert list(crop_box(positions)) == stored["tasks"]["reach-v3"]
    assert len(positions) > 3 * stored["episodes"]  # every step's hand and object, and each goal


def test_the_scripted_expert_solves_its_task_with_nothing_rendered():
    env = MetaWorldEnv(TASK, cameras=[])
    try:
        obs, _ = env.reset(seed=3)
        expert = env.spec_.make_expert(env)
        assert "pixels" not in obs or not obs["pixels"]
        steps, terminated, truncated = 0, False, False
        while not (terminated or truncated) and steps < 200:
            obs, _, terminated, truncated, info = env.step(expert.act())
            steps += 1
        assert info["is_success"] and terminated and steps < 200
    finally:
        env.close()


def test_the_episode_budget_is_the_envs_even_beyond_metaworlds_own_500_steps():
    env = MetaWorldEnv(TASK, cameras=[], episode_length=503)
    try:
        env.reset(seed=0)
        ends = [env.step(np.zeros(4, np.float32))[2:4] for _ in range(503)]
    finally:
        env.close()
    assert ends[-2] == (False, False) and ends[-1] == (False, True)


@pytest.mark.slow
def test_demonstrations_record_validate_view_train_and_evaluate_with_stock_lerobot(tmp_path):
    """`obsbench demos` on a Meta-World task: Meta-World's expert's successful episodes in the schema (80 fps, the
    oracle's values named), every space served (`obsbench validate`), a rerun finds them recorded, `obsbench view`
    writes the frame's cloud as .ply inside the crop box; then stock lerobot-train of the plugin's point-cloud ACT
    on them and stock lerobot-eval of that checkpoint on `--env.type=obsbench_metaworld`."""
    import json

    import open3d as o3d

    from lerobot_obsbench.cli import main

    out = tmp_path / "drawer"
    assert main(["demos", "--task", TASK, "--episodes", "2", "--out", str(out), "--image-size", "32"]) == 0
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["fps"] == 80 and info["robot_type"] == "sawyer"
    names = info["features"][schema.PRIVILEGED_STATE_KEY]["names"]
    assert names[:2] == ["object.x", "object.y"] and names[-1] == "goal.qz" and len(names) == 21
    assert {schema.image_key("corner2"), schema.depth_key("corner2")} <= set(info["features"])
    assert main(["validate", "--root", str(out)]) == 0
    assert main(["demos", "--task", TASK, "--episodes", "2", "--out", str(out), "--image-size", "32"]) == 0
    box = [-0.6, 0.6, 0.2, 1.0, -0.01, 0.6]
    ply = tmp_path / "frame.ply"
    view = ["view", "--root", str(out), "--frame", "10", "--out", str(tmp_path / "v.rrd"), "--ply", str(ply)]
    assert main([*view, "--workspace", *map(str, box)]) == 0
    points = np.asarray(o3d.io.read_point_cloud(str(ply)).points)
    assert len(points) > 200
    assert (points.min(axis=0) >= np.array(box[0::2]) - 1e-6).all()
    assert (points.max(axis=0) <= np.array(box[1::2]) + 1e-6).all()

    # stock lerobot-train of the plugin's ACT on point clouds, then stock lerobot-eval on the Meta-World env
    from lerobot_obsbench.presets import preset_args

    bin_dir = os.path.dirname(sys.executable)
    environment = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
    train = [
        f"{bin_dir}/lerobot-train",
        "--policy.type=obs_act",
        "--policy.obs_space=pointcloud",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        *preset_args("tiny", "obs_act", "pointcloud"),
        "--policy.point_features=xyz",
        f"--policy.workspace={box}",
        "--dataset.repo_id=local/drawer",
        f"--dataset.root={out}",
        "--batch_size=4",
        "--steps=2",
        "--save_freq=2",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={tmp_path / 'train'}",
    ]
    trained = subprocess.run(train, env=environment, capture_output=True, text=True, timeout=900)
    assert trained.returncode == 0, trained.stderr[-3000:]
    evaluate = [
        f"{bin_dir}/lerobot-eval",
        f"--policy.path={tmp_path / 'train' / 'checkpoints' / 'last' / 'pretrained_model'}",
        "--policy.device=cpu",
        "--env.type=obsbench_metaworld",
        f"--env.task={TASK}",
        "--env.image_size=32",
        "--env.episode_length=5",
        "--env.obs_space=pointcloud",  # the env renders depth alone: DP3's xyz points read no colour
        "--env.point_features=xyz",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        f"--output_dir={tmp_path / 'eval'}",
    ]
    evaluated = subprocess.run(evaluate, env=environment, capture_output=True, text=True, timeout=900)
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    metrics = json.loads((tmp_path / "eval" / "eval_info.json").read_text())["overall"]
    assert metrics["n_episodes"] == 1 and "pc_success" in metrics


@pytest.mark.slow
def test_a_metaworld_grid_runs_from_nothing_to_its_report(tmp_path):
    """`obsbench run` on a Meta-World grid: demonstrations, the controls and a point-cloud policy (DP3 on xyz
    points, so its env renders depth alone) trained, each evaluated on the task's test seeds, and the report reads
    the results."""
    import json

    from lerobot_obsbench.cli import main

    grid = tmp_path / "mw.yaml"
    grid.write_text(
        "tasks: [drawer-open-v3]\nobs_spaces: [none, state, pointcloud]\npreset: tiny\nseeds: [1000]\ndemos: [2]\n"
        "batch_size: 4\nsteps: 2\ncheckpoints: 1\nimage_size: 32\neval_episodes: 1\nepisode_length: 5\n"
        "encoders: {pointcloud: [dp3]}\nspace_overrides: {pointcloud: {point_features: xyz}}\n"
    )
    out = tmp_path / "out"
    assert main(["run", str(grid), "--out", str(out), "--workers", "1"]) == 0
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    methods = {r["method"] for r in records if r["kind"] == "eval" and r["split"] == "test"}
    assert methods == {"obs_act/none/blind", "obs_act/state/oracle", "obs_act/pointcloud/dp3"}
    assert main(["report", str(out / "results.jsonl"), "--out", str(tmp_path / "report")]) == 0
    assert "drawer-open-v3" in (tmp_path / "report" / "report.md").read_text()
