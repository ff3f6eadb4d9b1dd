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
    oracle's values named), every space served (`obsbench validate`), a rerun finds them recorded, `obsbench replay`
    replays them open-loop to their recorded success, `obsbench view`
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
    # replayed open-loop in Meta-World (it used to look the task up among ManiSkill's: "Unknown task")
    assert main(["replay", "--root", str(out)]) == 0
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
    """`obsbench run` on a Meta-World grid: demonstrations, the blind control and a point-cloud policy (DP3 on xyz
    points, so its env renders depth alone) trained, each evaluated on the task's test seeds, the point-cloud one also
    with the camera moved and with a depth sensor's noise, and the report reads the results and shows the share of
    its success kept."""
    import json

    from lerobot_obsbench.cli import main

    grid = tmp_path / "mw.yaml"
    grid.write_text(
        "tasks: [drawer-open-v3]\nobs_spaces: [none, pointcloud]\npreset: tiny\nseeds: [1000]\ndemos: [2]\n"
        "batch_size: 4\nsteps: 2\ncheckpoints: 1\nimage_size: 32\neval_episodes: 2\nepisode_length: 5\n"
        "encoders: {pointcloud: [dp3]}\nspace_overrides: {pointcloud: {point_features: xyz}}\n"
        "perturbations: [camera_yaw:5, depth_noise:1]\nperturbed_episodes: 1\n"
    )
    out = tmp_path / "out"
    assert main(["run", str(grid), "--out", str(out), "--workers", "2", "--threads", "1"]) == 0
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    tests = [r for r in records if r["kind"] == "eval" and r["split"] == "test"]
    assert {r["method"] for r in tests} == {"obs_act/none/blind", "obs_act/pointcloud/dp3"}
    perturbed = {r["perturbation"]: r for r in tests if r["method"] == "obs_act/pointcloud/dp3"}
    assert set(perturbed) == {"none", "camera_yaw:5", "depth_noise:1"}
    assert perturbed["none"]["episodes"] == 2 and perturbed["depth_noise:1"]["per_seed"]["seeds"] == [0]
    assert main(["report", str(out / "results.jsonl"), "--out", str(tmp_path / "report")]) == 0
    md = (tmp_path / "report" / "report.md").read_text()
    assert "drawer-open-v3" in md and "Robustness: the share of the unperturbed success kept" in md


# ---- zero-shot perturbations (envs/metaworld/perturbations.py): each changes what it says and nothing else ----------


def _perturbed_frame(perturbation: str | None, seed: int = 3, size: int = 64):
    env = MetaWorldEnv("reach-v3", cameras=["corner2"], image_size=size, perturbation=perturbation)
    try:
        env.reset(seed=seed)
        return env.schema_frame(), env.segmentation("corner2"), env
    finally:
        env.close()


def test_a_moved_camera_orbits_its_look_at_point_and_its_cloud_still_lies_on_the_table():
    """camera_yaw / camera_pitch: the frames change, the intrinsics and the objects do not; the camera keeps its
    distance to its look-at point on the table top and still looks at it; its depth, unprojected with its new pose,
    puts the table's pixels on the table's surface within the millimetre depth is rounded to."""
    import torch

    from lerobot_obsbench.envs.metaworld.perturbations import look_at_point, table_top

    nominal, _, env = _perturbed_frame(None)
    model, data = env._env.model, env._env.data
    top, height = table_top(model, data)
    pose = nominal[schema.cam2world_key("corner2")]
    target = pose[:3, 3] + pose[:3, 2] * (height - pose[2, 3]) / pose[2, 2]  # OpenCV's z is the optical axis
    for name in ("camera_yaw:10", "camera_pitch:10", "camera_yaw:-5"):
        frame, shows, moved = _perturbed_frame(name)
        moved_pose = frame[schema.cam2world_key("corner2")]
        assert np.abs(frame[schema.image_key("corner2")].astype(int) - nominal[schema.image_key("corner2")]).mean() > 5
        assert np.array_equal(frame[schema.intrinsics_key("corner2")], nominal[schema.intrinsics_key("corner2")])
        assert np.array_equal(frame[schema.PRIVILEGED_STATE_KEY], nominal[schema.PRIVILEGED_STATE_KEY])
        assert np.linalg.norm(moved_pose[:3, 3] - pose[:3, 3]) > 0.05
        assert np.linalg.norm(moved_pose[:3, 3] - target) == pytest.approx(
            np.linalg.norm(pose[:3, 3] - target), abs=1e-5
        )
        hit = moved_pose[:3, 3] + moved_pose[:3, 2] * (height - moved_pose[2, 3]) / moved_pose[2, 2]
        assert np.linalg.norm(hit - target) < 1e-4  # still looking at the same point
        mujoco_rotation = moved_pose[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # corner2's image is turned (TURNED_CAMERAS)
        assert look_at_point(moved_pose[:3, 3], mujoco_rotation.flatten(), height) == pytest.approx(target, abs=1e-4)
        depth = frame[schema.depth_key("corner2")][..., 0].astype(np.float32) / 1000
        world = geometry.transform_points(
            geometry.unproject_depth(
                torch.from_numpy(depth)[None], torch.from_numpy(frame[schema.intrinsics_key("corner2")])[None]
            ),
            torch.from_numpy(moved_pose)[None],
        )[0].numpy()
        on_table = (shows == top) & (depth > 0)
        assert on_table.sum() > 300
        distances = _surface_distance(moved._env.model, moved._env.data, top, world[on_table])
        assert distances.max() < 1.5e-3  # on the table's box (its top, and a side the moved camera sees)
        assert np.median(np.abs(world[on_table][:, 2] - height)) < 1e-3  # most on its top
        with pytest.raises(Exception, match="look down at the table"):
            look_at_point(np.zeros(3), np.diag([1.0, -1.0, -1.0]).flatten(), 1.0)  # looking up: no point on the table


def test_light_and_background_change_the_colour_only_where_they_say():
    nominal, shows, env = _perturbed_frame(None)
    rgb = nominal[schema.image_key("corner2")].astype(float)
    from lerobot_obsbench.envs.metaworld.perturbations import background_geoms

    surfaces = np.isin(shows, background_geoms(env._env.model, env._env.data))
    for name, darker in (("light:0.03", True), ("light:1.2", False)):
        frame, _, _ = _perturbed_frame(name)
        lit = frame[schema.image_key("corner2")].astype(float)
        assert (lit.mean() < 0.5 * rgb.mean()) if darker else (lit.mean() > 1.3 * rgb.mean())
        for key in (schema.depth_key("corner2"), schema.cam2world_key("corner2"), schema.PRIVILEGED_STATE_KEY):
            assert np.array_equal(frame[key], nominal[key])
    frame, background_shows, _ = _perturbed_frame("background:1,0.2,0.2")
    coloured = frame[schema.image_key("corner2")].astype(float)
    assert np.array_equal(background_shows, shows)  # the same geoms in the same pixels
    assert np.array_equal(frame[schema.depth_key("corner2")], nominal[schema.depth_key("corner2")])
    red = coloured[surfaces]
    assert (red[:, 0] > 1.5 * red[:, 1]).mean() > 0.95  # the table and floor are red now, which they were not
    assert (rgb[surfaces][:, 0] > 1.5 * rgb[surfaces][:, 1]).mean() < 0.5
    change = np.abs(coloured - rgb).mean(axis=-1)
    assert change[surfaces].mean() > 4 * change[~surfaces & (shows >= 0)].mean()  # the rest keeps its colour


def test_depth_noise_changes_the_depth_alone_and_an_episode_repeats_its_noise():
    nominal, _, _ = _perturbed_frame(None)
    first, _, _ = _perturbed_frame("depth_noise:2")
    again, _, _ = _perturbed_frame("depth_noise:2")
    other, _, _ = _perturbed_frame("depth_noise:2", seed=4)
    key = schema.depth_key("corner2")
    for k in (schema.image_key("corner2"), schema.cam2world_key("corner2"), schema.PRIVILEGED_STATE_KEY):
        assert np.array_equal(first[k], nominal[k])
    assert not np.array_equal(first[key], nominal[key]) and np.array_equal(first[key], again[key])
    holes = (first[key] == 0) & (nominal[key] > 0)
    assert holes.sum() > 0.01 * holes.size
    nominal_other, _, _ = _perturbed_frame(None, seed=4)
    assert not np.array_equal(other[key] - nominal_other[key], first[key] - nominal[key])


def test_a_perturbation_meta_world_does_not_apply_is_refused_before_anything_slow():
    started = time.perf_counter()
    with pytest.raises(Exception, match=r"noise:16: Meta-World tasks do not support noise perturbations; they take"):
        MetaWorldEnv(TASK, perturbation="noise:16")
    assert time.perf_counter() - started < 1


def test_an_image_larger_than_metaworlds_framebuffer_renders_at_its_size():
    """Meta-World's scene asks MuJoCo for a 640 x 480 offscreen framebuffer; a larger image used to pass every check
    and stop in MuJoCo with a traceback advising to edit the model's XML (demos, grids, lerobot-eval alike)."""
    env = MetaWorldEnv("reach-v3", cameras=["corner2"], image_size=672)
    try:
        obs, _ = env.reset(seed=0)
        assert obs["pixels"]["corner2"].shape == (672, 672, 3)
        assert obs["robot_state"]["depth.corner2"].shape == (672, 672, 1)
    finally:
        env.close()
