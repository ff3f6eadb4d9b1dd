"""The device check's bundle (scripts/device_bundle.py, scripts/device_install.py): wheels trimmed with a valid
RECORD, parts within their limit, and the parts installed one call at a time into a scratch target with pip's
--no-index, on wheels, a Debian package and a checkpoint archive the tests build; the check's own options and time
budget (benchmarks/device_check.py; its end-to-end CPU run is in test_sim.py)."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

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
    assert done.returncode == 1 and "onepkg-1.0-py3-none-any.whl is corrupt" in done.stderr
    assert not (tmp_path / "site").exists()
    not_a_part = subprocess.run([sys.executable, str(INSTALL), str(tmp_path / "w")], capture_output=True, text=True)
    assert not_a_part.returncode == 2 and "no manifest.json" in not_a_part.stderr


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


def test_a_check_out_of_time_skips_its_stages_and_still_writes_its_json(tmp_path):
    device_check.main(["--device", "cpu", "--out", str(tmp_path), "--budget-s", "0"])
    result = json.loads((tmp_path / "device_check.json").read_text())
    assert list(result["stages"]) == list(device_check.STAGES)
    assert all(not s["ok"] and "budget of 0 s was spent" in s["skipped"] for s in result["stages"].values())


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
