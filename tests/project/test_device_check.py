"""The device check's bundle (scripts/device_bundle.py, scripts/device_install.py): wheels trimmed with a valid
RECORD, parts within their limit, and the parts installed one call at a time into a scratch target with pip's
--no-index, on wheels, a Debian package and a checkpoint archive the tests build; the check's own options and time
budget (benchmarks/device_check.py; its end-to-end CPU run is in test_sim.py)."""

from __future__ import annotations

import base64
import hashlib
import io
import json
import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path
from types import SimpleNamespace

import pytest

from benchmarks import device_check
from scripts import device_bundle
from scripts.device_bundle import Item, Trim, pack, trim_wheel, write_parts
from tests.support.paths import REPO_ROOT as ROOT

INSTALL = ROOT / "scripts" / "device_install.py"


def make_wheel(folder: Path, name: str, files: dict[str, bytes]) -> Path:
    """A pure-Python wheel of `name` 1.0 holding `files` (package-relative paths -> contents), RECORD included."""
    info = f"{name}-1.0.dist-info"
    contents = {
        **{f"{name}/{path}": data for path, data in files.items()},
        f"{info}/METADATA": f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.0\n".encode(),
        f"{info}/WHEEL": b"Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
    }
    record = []
    for path, data in contents.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{path},sha256={digest},{len(data)}")
    contents[f"{info}/RECORD"] = ("\n".join([*record, f"{info}/RECORD,,"]) + "\n").encode()
    wheel = folder / f"{name}-1.0-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        for path, data in contents.items():
            archive.writestr(path, data)
    return wheel


def make_deb(folder: Path) -> Path:
    tree = folder / "deb-tree"
    (tree / "DEBIAN").mkdir(parents=True)
    (tree / "DEBIAN" / "control").write_text(
        "Package: obsbench-test-lib\nVersion: 1.0\nArchitecture: amd64\nMaintainer: tests\nDescription: test\n"
    )
    (tree / "usr" / "lib").mkdir(parents=True)
    (tree / "usr" / "lib" / "libobsbenchtest.so.1").write_bytes(b"\x7fELF not really")
    deb = folder / "obsbench-test-lib_1.0_amd64.deb"
    subprocess.run(["dpkg-deb", "--build", "--root-owner-group", str(tree), str(deb)], check=True, capture_output=True)
    return deb


def test_a_trimmed_wheel_keeps_code_and_the_kept_assets_and_its_record_matches(tmp_path):
    source = make_wheel(
        tmp_path,
        "simpkg",
        {
            "__init__.py": b"VALUE = 1\n",
            "assets/robots/arm/arm.urdf": b"<robot/>",
            "assets/robots/other/big.glb": os.urandom(5000),
            "assets/maps/sky.exr": os.urandom(3000),
            "assets/robots/notes.py": b"# code under a dropped folder stays\n",
        },
    )
    target = tmp_path / "trimmed" / source.name
    target.parent.mkdir()
    trim = Trim(drop=("simpkg/assets/*",), keep=("simpkg/assets/robots/arm/*",), why="arm only")
    note = trim_wheel(source, target, trim)
    assert note["dropped_files"] == 2 and note["kept"] == "arm only"
    with zipfile.ZipFile(target) as archive:
        names = set(archive.namelist())
        record = archive.read("simpkg-1.0.dist-info/RECORD").decode().splitlines()
        for line in record:
            path, digest, size = line.split(",")
            if path.endswith("RECORD"):
                continue
            data = archive.read(path)
            assert digest == "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            assert int(size) == len(data)
    assert "simpkg/assets/robots/arm/arm.urdf" in names and "simpkg/assets/robots/notes.py" in names
    assert not names & {"simpkg/assets/robots/other/big.glb", "simpkg/assets/maps/sky.exr"}
    assert {line.split(",")[0] for line in record} == names
    site = tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--target", str(site), str(target)]
    subprocess.run(pip, check=True)
    assert (site / "simpkg" / "assets" / "robots" / "arm" / "arm.urdf").read_bytes() == b"<robot/>"
    assert not (site / "simpkg" / "assets" / "maps").exists()


def test_parts_stay_within_the_limit_and_a_large_file_is_cut_into_pieces(tmp_path):
    sizes = {"a": 2500, "b": 900, "c": 900, "d": 300, "e": 10}
    items = []
    for name, size in sizes.items():
        (tmp_path / name).write_bytes(os.urandom(size))
        items.append(Item(name, "wheel", tmp_path / name))
    parts = pack(items, 1000)
    assert all(sum(piece["size"] for piece in part) <= 1000 for part in parts)
    pieces = [piece for part in parts for piece in part]
    assert sorted(p["name"] for p in pieces if p["item"].name == "a") == ["a.000", "a.001", "a.002"]
    for name, size in sizes.items():
        assert sum(p["size"] for p in pieces if p["item"].name == name) == size
    assert len(parts) == 5  # 2500 + 900 + 900 + 300 + 10 bytes cannot share fewer parts of 1000


def test_parts_installed_one_call_at_a_time_end_up_complete(tmp_path):
    build = tmp_path / "build"
    build.mkdir()
    big = make_wheel(build, "bigpkg", {"__init__.py": b"import pathlib\n", "blob.bin": os.urandom(150_000)})
    small = make_wheel(build, "smallpkg", {"__init__.py": b"from bigpkg import pathlib\nOK = 1\n"})
    checkpoint = build / "ckpt"
    checkpoint.mkdir()
    (checkpoint / "config.json").write_text('{"type": "obs_act"}')
    archive = build / "checkpoint.tar"
    with tarfile.open(archive, "w") as tar:
        tar.add(checkpoint, arcname="checkpoint")
    items = [
        Item(big.name, "wheel", big),
        Item(small.name, "wheel", small),
        Item(archive.name, "tar", archive),
        Item("obsbench-test-lib_1.0_amd64.deb", "deb", make_deb(build)),
    ]
    bundle = tmp_path / "bundle"
    bundle.mkdir()
    missing = [{"what": "a library", "why": "not here"}]
    manifest = write_parts(items, bundle, 64 * 1024, missing)
    parts = sorted(bundle.glob("part-*"))
    assert len(parts) == len(manifest["parts"]) >= 3
    assert all(sum(f.stat().st_size for f in p.iterdir() if f.name != "manifest.json") <= 64 * 1024 for p in parts)
    assert json.loads((parts[0] / "manifest.json").read_text()) == manifest
    assert manifest["missing"] == missing
    big_parts = {piece["part"] for item in manifest["items"] if item["name"] == big.name for piece in item["pieces"]}
    assert len(big_parts) == 3  # 150 kB in pieces of 64 KiB

    target, stash, root = tmp_path / "site", tmp_path / "stash", tmp_path / "root"
    outputs = []
    for part in parts:
        install = [sys.executable, str(INSTALL), str(part), "--target", str(target), "--stash", str(stash)]
        done = subprocess.run([*install, "--root", str(root)], capture_output=True, text=True, check=True)
        outputs.append(done.stdout)
        if part != parts[-1]:
            assert "still to come" in done.stdout
    assert "the bundle is complete" in outputs[-1]
    check = [sys.executable, "-c", "import smallpkg, bigpkg; print(smallpkg.OK, len((bigpkg.__path__[0]))>0)"]
    imported = subprocess.run(check, env={**os.environ, "PYTHONPATH": str(target)}, capture_output=True, text=True)
    assert imported.stdout.split() == ["1", "True"], imported.stderr
    assert (target / "bigpkg" / "blob.bin").stat().st_size == 150_000
    assert (root / "usr" / "lib" / "libobsbenchtest.so.1").read_bytes() == b"\x7fELF not really"
    assert json.loads((stash / "checkpoint" / "config.json").read_text()) == {"type": "obs_act"}
    # a part given again installs nothing twice
    again = subprocess.run(
        [sys.executable, str(INSTALL), str(parts[0]), "--target", str(target), "--stash", str(stash)],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "installed 0 ()" in again.stdout


def test_a_corrupt_piece_is_refused_and_a_folder_without_a_manifest_is_not_a_part(tmp_path):
    (tmp_path / "w").mkdir()
    wheel = make_wheel(tmp_path / "w", "onepkg", {"__init__.py": b"X = 1\n"})
    bundle = tmp_path / "bundle"
    bundle.mkdir()
    write_parts([Item(wheel.name, "wheel", wheel)], bundle, 2**20, [])
    piece = bundle / "part-00" / wheel.name
    piece.write_bytes(piece.read_bytes()[:-1] + b"!")
    install = [sys.executable, str(INSTALL), str(bundle / "part-00"), "--target", str(tmp_path / "site")]
    done = subprocess.run([*install, "--stash", str(tmp_path / "stash")], capture_output=True, text=True)
    refused_in_one_line(done, "part-00/onepkg-1.0-py3-none-any.whl is not the piece its manifest lists")
    assert not (tmp_path / "site").exists()
    not_a_part = subprocess.run([sys.executable, str(INSTALL), str(tmp_path / "w")], capture_output=True, text=True)
    refused_in_one_line(not_a_part, "no manifest.json")


def make_tar(path: Path, files: dict[str, bytes]) -> Path:
    with tarfile.open(path, "w") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return path


def make_bundle(folder: Path, config: bytes, blob: bytes) -> list[Path]:
    """A bundle of two archives, the larger cut into pieces over several parts: its part folders."""
    build = folder / "build"
    build.mkdir(parents=True)
    items = [
        Item("checkpoint.tar", "tar", make_tar(build / "checkpoint.tar", {"checkpoint/config.json": config})),
        Item("blob.tar", "tar", make_tar(build / "blob.tar", {"blob/data.bin": blob})),
    ]
    write_parts(items, folder / "bundle", 64 * 1024, [])
    return sorted((folder / "bundle").glob("part-*"))


def install_part(part: Path, stash: Path) -> subprocess.CompletedProcess:
    install = [sys.executable, str(INSTALL), str(part), "--target", str(stash.parent / "site"), "--stash", str(stash)]
    return subprocess.run([*install, "--root", str(stash.parent / "root")], capture_output=True, text=True)


def refused_in_one_line(done: subprocess.CompletedProcess, *wanted: str) -> None:
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.startswith("device_install: ") and done.stderr.count("\n") == 1, done.stderr
    assert all(text in done.stderr for text in wanted), done.stderr


@pytest.mark.parametrize("second", ["the same part again", "another part"])
def test_a_part_of_another_bundle_is_refused_saying_what_differs(tmp_path, second):
    blob = os.urandom(150_000)
    first = make_bundle(tmp_path / "a", b'{"type": "obs_act"}', blob)
    rebuilt = make_bundle(tmp_path / "b", b'{"type": "obs_diffusion"}', blob)  # a new checkpoint, the same blob
    assert [p.name for p in first] == [p.name for p in rebuilt] and len(first) == 3
    stash = tmp_path / "stash"
    for part in first if second == "the same part again" else first[:1]:
        assert install_part(part, stash).returncode == 0
    stashed = {p.name: p.read_bytes() for p in (stash / "pieces").iterdir()}
    part = rebuilt[-1] if second == "the same part again" else rebuilt[1]
    done = install_part(part, stash)
    refused_in_one_line(done, f"{part.name} belongs to another bundle", "checkpoint.tar differs", f"rm -rf {stash}")
    assert "blob.tar" not in done.stderr  # the same file in both bundles is not named as a difference
    assert {p.name: p.read_bytes() for p in (stash / "pieces").iterdir()} == stashed
    if second == "the same part again":
        assert json.loads((stash / "checkpoint" / "config.json").read_text()) == {"type": "obs_act"}


def test_a_piece_is_checked_by_its_sha256_in_the_part_that_carries_it(tmp_path):
    """A damaged piece of a file cut over several parts is refused when its own part arrives, not after the last."""
    parts = make_bundle(tmp_path, b"{}", os.urandom(150_000))
    manifest = json.loads((parts[0] / "manifest.json").read_text())
    piece = next(p for item in manifest["items"] for p in item["pieces"] if p["part"] == "part-00")
    damaged = parts[0] / piece["name"]
    damaged.write_bytes(damaged.read_bytes()[:-1] + b"!")
    stash = tmp_path / "stash"
    refused_in_one_line(install_part(parts[0], stash), f"part-00/{piece['name']}", "sha256", "copy part-00 again")
    assert not (stash / "pieces" / piece["name"]).exists()


@pytest.mark.parametrize(
    "damage, wanted",
    [
        ("a piece removed", ["part-01 lacks", "copy part-01 again"]),
        ("the manifest truncated", ["part-01/manifest.json", "truncated or damaged", "copy part-01 again"]),
        ("the manifest not JSON", ["part-01/manifest.json", "truncated or damaged"]),
        ("the manifest of another shape", ["part-01/manifest.json", "not a manifest of scripts/device_bundle.py"]),
        ("a piece without its sha256", ["part-01/manifest.json", "sha256", "rebuild the bundle"]),
        ("the folder renamed", ["part-1 is not one of its manifest's parts (part-00, part-01, part-02)"]),
    ],
)
def test_an_incomplete_part_or_a_damaged_manifest_is_refused_in_one_line(tmp_path, damage, wanted):
    parts = make_bundle(tmp_path, b"{}", os.urandom(150_000))
    part = parts[1]
    manifest_path = part / "manifest.json"
    text = manifest_path.read_text()
    manifest = json.loads(text)
    if damage == "a piece removed":
        next(p for p in part.iterdir() if p.name != "manifest.json").unlink()
    elif damage == "the manifest truncated":
        manifest_path.write_text(text[: len(text) // 2])
    elif damage == "the manifest not JSON":
        manifest_path.write_bytes(b"\x00\xff" * 100)
    elif damage == "the manifest of another shape":
        manifest_path.write_text(json.dumps({"items": 3}))
    elif damage == "a piece without its sha256":
        del manifest["items"][0]["pieces"][0]["sha256"]
        manifest_path.write_text(json.dumps(manifest))
    else:
        part = part.rename(part.with_name("part-1"))
    stash = tmp_path / "stash"
    refused_in_one_line(install_part(part, stash), *wanted)
    assert not (stash / "pieces").is_dir() or not any((stash / "pieces").iterdir())


def test_the_part_limit_leaves_room_for_the_working_tree():
    with pytest.raises(SystemExit):
        device_bundle.main(["--part-mib", "61"])


@pytest.mark.slow
def test_the_bundle_carries_what_the_check_imports_and_the_image_lacks():
    """The distributions the check's modules load, less the GPU image's: the simulator, LeRobot and its dataset
    stack, never torch or numpy (the image's) nor this plugin (its own wheel is built apart)."""
    from importlib.metadata import version

    needed = device_bundle.needed_distributions(with_spconv=True)
    assert {"lerobot", "mani-skill", "sapien", "av", "diffusers", "gymnasium", "datasets", "draccus"} <= set(needed)
    assert not {"torch", "numpy", "lerobot-policy-obsbench", "huggingface-hub", "opencv-python"} & set(needed)
    assert needed["lerobot"] == "0.6.1" and needed["mani-skill"] == "3.0.1"
    # SpUNet-34 on the GPU: spconv's CUDA build at this venv's (CPU) spconv version, never the CPU one
    assert needed["spconv-cu126"] == version("spconv") and needed["cumm-cu126"] == version("cumm")
    assert "spconv" not in needed and "cumm" not in needed


@pytest.fixture
def stages_stubbed(monkeypatch):
    """Every stage replaced by one that records that it ran, and a clock that advances 100 s at each reading: the
    scheduling and the refusals are tested without the stages' work or real time."""
    ran = []
    for name in device_check.STAGES:
        monkeypatch.setattr(device_check.DeviceCheck, name, lambda self, name=name: ran.append(name) or {"ran": name})
    clock = iter(range(0, 10**9, 100))
    monkeypatch.setattr(device_check, "time", SimpleNamespace(time=lambda: next(clock)))
    return ran


def test_out_of_time_the_machine_and_imports_stages_still_run_and_the_rest_are_skipped(stages_stubbed, tmp_path):
    device_check.main(["--device", "cpu", "--out", str(tmp_path), "--budget-s", "50"])
    result = json.loads((tmp_path / "device_check.json").read_text())
    assert stages_stubbed == ["machine", "imports"]
    assert list(result["stages"]) == list(device_check.STAGES)
    assert result["stages"]["machine"] == {"ok": True, "ran": "machine", "seconds": 100}
    assert result["stages"]["imports"]["ok"] and result["stages"]["imports"]["ran"] == "imports"
    skipped = [result["stages"][name] for name in device_check.STAGES[2:]]
    assert all(not s["ok"] and "the budget of 50 s was spent" in s["skipped"] for s in skipped)


def test_the_budget_is_read_by_the_projects_number_rule():
    """The check reads --budget-s without importing the plugin (its machine and imports stages must run where the
    plugin does not import), so its reading is held here to lerobot_obsbench.numeric's for the same bounds."""
    import argparse

    from lerobot_obsbench.numeric import number_argument

    rule = number_argument(above=0)
    for text in ("420", "0.5", "1e3", " 7 ", "0", "-1", "nan", "-inf", "inf", "1e400", "soon", "", "True"):
        outcomes = []
        for read in (rule, device_check.budget_seconds):
            try:
                outcomes.append(("accepted", read(text)))
            except argparse.ArgumentTypeError as err:
                outcomes.append(("refused", str(err)))
        assert outcomes[0] == outcomes[1], text


@pytest.mark.parametrize(
    "budget, message",
    [
        ("0", "argument --budget-s: must be a finite number > 0, got 0"),
        ("-60", "argument --budget-s: must be a finite number > 0, got -60"),
        ("nan", "argument --budget-s: must be a finite number > 0, got nan"),
        ("inf", "argument --budget-s: must be a finite number > 0, got inf"),
        ("7min", "argument --budget-s: expected a finite number > 0, got '7min'"),
    ],
)
def test_a_budget_that_is_not_a_finite_number_above_zero_is_refused_before_any_stage(
    stages_stubbed, tmp_path, capsys, budget, message
):
    out = tmp_path / "check"
    with pytest.raises(SystemExit) as exit_:
        device_check.main(["--device", "cpu", "--out", str(out), "--budget-s", budget])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and message in err and "Traceback" not in err
    assert stages_stubbed == [] and not out.exists()


@pytest.mark.parametrize(
    "case, message",
    [
        ("a file", "is a file; give a folder"),
        ("a folder holding a device_check.json written by hand", "add --overwrite to replace what is there"),
        ("a folder holding a check of another task", "not this command's own output of the same inputs"),
        ("the checkpoint", "would write over this command's input"),
        ("under a file", "is a file, so the folder cannot be created"),
    ],
)
def test_an_out_folder_it_cannot_or_may_not_write_is_refused_before_any_stage(
    stages_stubbed, tmp_path, capsys, case, message
):
    """Refused as lerobot_obsbench/outputs.py refuses a command's output folder, in the same words (the check
    decides without importing the plugin, whose import its imports stage reports on)."""
    from lerobot_obsbench.outputs import OutputPathError, check_output_folder

    checkpoint = tmp_path / "pretrained_model"
    checkpoint.mkdir()
    (checkpoint / "config.json").write_text("{}")
    notes = tmp_path / "notes.txt"
    notes.write_text("my own notes\n")
    by_hand = tmp_path / "by-hand"
    by_hand.mkdir()
    (by_hand / "device_check.json").write_text("my own notes\n")
    other_task = tmp_path / "other-task"
    device_check.main(
        ["--device", "cpu", "--task", "PickCube-v1", "--checkpoint", str(checkpoint), "--out", str(other_task)]
    )
    earlier = (other_task / "device_check.json").read_text()
    stages_stubbed.clear()
    out = {
        "a file": notes,
        "a folder holding a device_check.json written by hand": by_hand,
        "a folder holding a check of another task": other_task,
        "the checkpoint": checkpoint,
        "under a file": notes / "check",
    }[case]
    argv = ["--device", "cpu", "--checkpoint", str(checkpoint), "--out", str(out), "--budget-s", "1"]
    with pytest.raises(SystemExit) as exit_:
        device_check.main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and f"--out {out}" in err and message in err and "Traceback" not in err
    assert stages_stubbed == [] and notes.read_text() == "my own notes\n"
    assert (by_hand / "device_check.json").read_text() == "my own notes\n"
    assert (other_task / "device_check.json").read_text() == earlier
    assert sorted(p.name for p in checkpoint.iterdir()) == ["config.json"]
    writer = device_check.made_by("cpu", device_check.TASK, checkpoint)
    with pytest.raises(OutputPathError) as refused:
        check_output_folder(out, "--out", [checkpoint], [device_check.RESULT], writer)
    assert f"error: {refused.value}\n" in err


def test_an_out_folder_with_the_checks_own_json_is_rewritten_and_another_one_only_when_told(stages_stubbed, tmp_path):
    from lerobot_obsbench.outputs import is_own_output

    device_check.main(["--device", "cpu", "--out", str(tmp_path), "--stages", "machine"])
    device_check.main(["--device", "cpu", "--out", str(tmp_path), "--stages", "preprocess"])  # its own: rewritten
    result = tmp_path / device_check.RESULT
    assert list(json.loads(result.read_text())["stages"]) == ["machine", "imports", "preprocess"]
    assert is_own_output(result, device_check.made_by("cpu", device_check.TASK, None))  # the package's record
    result.write_text("my own notes\n")
    device_check.main(["--device", "cpu", "--out", str(tmp_path), "--stages", "machine", "--overwrite"])
    assert json.loads(result.read_text())["benchmark"] == "device_check"
    assert (tmp_path / "device_check.log").read_text().count("== machine") == 3  # the log is appended to, kept


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--stages", "gpu_sim"], "--stages: unknown ['gpu_sim']"),
        (["--checkpoint", "."], "no config.json there"),
    ],
)
def test_the_check_refuses_what_it_cannot_run(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit) as exit_:
        device_check.main(["--device", "cpu", "--out", str(tmp_path), *argv])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
