"""Pack what an offline GPU node lacks for the device check (benchmarks/device_check.py) into parts of a size
you choose, for a transfer that limits what one copy carries.

The node this is sized for has Python 3.12 with PyTorch, Triton and CuPy, but no LeRobot, ManiSkill, SAPIEN or
Vulkan loader, and reaches no network. This builder, run where the project is installed:

1. imports the check's modules (`device_check.MODULES`) in this venv and keeps the distributions they loaded that
   the machine's image lacks (`IMAGE_PACKAGES`), at this venv's versions; downloads their Python 3.12 x86-64
   wheels from PyPI (one with no wheel there, fpsample, is built here), and builds this plugin's own;
2. trims ManiSkill to its code and the assets of the check's task (`TRIMS`), SAPIEN of its C++ headers and its
   stereo sensor's patterns, which neither the check nor the imports open;
3. downloads Debian's Vulkan loader packages (the device tool's list);
4. adds the checkpoint the check evaluates (`--checkpoint`), and SAPIEN's GPU PhysX library where this machine
   has it (SAPIEN downloads it from GitHub at the first GPU simulation; the manifest says when it is missing);
5. packs it all into parts of at most `--part-mib` MiB (a larger file is cut into pieces that the installer joins),
   each part with the manifest: every file and every piece with its size and SHA-256, which the installer checks
   (and by which it tells one bundle from another).

    .venv/bin/python -m scripts.device_bundle --checkpoint outputs/.../pretrained_model [--out .device_bundle]
        [--part-mib 56] [--with-spconv]

Then, on the GPU node, one install per part copied there (`.device_bundle/part-NN`, beside a checkout of this
repository; the stash in /tmp must survive between parts), then the check:

    python3 scripts/device_install.py .device_bundle/part-00      # ... part-01, ...
    PYTHONPATH=.:/tmp/obsbench-site python3 -m benchmarks.device_check --device cuda \\
        --checkpoint /tmp/obsbench-bundle/checkpoint --out $OUT

The default 56 MiB leaves room for the repository's working tree (~5 MiB) in a 64 MiB transfer.
"""

from __future__ import annotations

import argparse
import base64
import fnmatch
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import tarfile
import zipfile
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MIB = 2**20
# What the GPU machines' image ('cuda') holds, as the device tool listed it on 2026-11-17: a distribution named
# here is not carried (its version there serves). Names are compared normalised (PEP 503).
IMAGE_PACKAGES = """
absl-py accelerate aiofiles aiohappyeyeballs aiohttp aiosignal annotated-doc anyio attrs botorch build certifi
charset-normalizer chex click cloudpickle cmake colorama contourpy coverage cuda-bindings cuda-core cuda-pathfinder
cuda-toolkit cupy-cuda13x cycler cython diffrax e3nn einops equinox etils execnet filelock flatbuffers flax
fonttools formulaic frozenlist fsspec gpytorch grpcio h11 h5py hf-xet httpcore httpx huggingface-hub humanize
hypothesis idna imageio iniconfig interface-meta jax jax-cuda13-pjrt jax-cuda13-plugin jaxlib jaxtyping jinja2
joblib kiwisolver lazy-loader lightning lightning-utilities linear-operator lineax llvmlite lxml markdown
markdown-it-py markupsafe matplotlib mdurl meson ml-dtypes mpi4py mpmath msgpack multidict multipledispatch
mypy-extensions nanobind narwhals networkx ninja numba numba-cuda numpy numpyro nvidia-cublas nvidia-cuda-cupti
nvidia-cuda-nvrtc nvidia-cuda-runtime nvidia-cudnn-cu13 nvidia-cufft nvidia-cufile nvidia-curand nvidia-cusolver
nvidia-cusparse nvidia-cusparselt-cu13 nvidia-ml-py nvidia-nccl-cu13 nvidia-nvjitlink nvidia-nvshmem-cu13
nvidia-nvtx onnx onnx-ir onnxruntime onnxscript opencv-python-headless optax opt-einsum opt-einsum-fx optimistix
orbax-checkpoint packaging pandas pathspec patsy peft pillow pip pluggy portalocker prometheus-client propcache
protobuf psutil pyarrow pybind11 py-cpuinfo pygments pyre-extensions pytest pytest-benchmark pytest-cov
pytest-mock pytest-timeout pytest-xdist python-dateutil pytorch-lightning pyyaml regex requests rich sacrebleu
safetensors scikit-build-core scikit-image scikit-learn scipy seaborn sentencepiece sentence-transformers
setuptools shellingham simplejson six sortedcontainers statsmodels sympy tabulate tensorboard
tensorboard-data-server tensorstore threadpoolctl tifffile tiktoken timm tokenizers toolz torch torchaudio
torchdiffeq torch-geometric torchmetrics torchvision tqdm transformers treescope triton typer typing-extensions
typing-inspect urllib3 uvloop wadler-lindig werkzeug wheel wrapt xarray xxhash yarl zipp
""".split()
# This plugin travels as source with the working tree.
OWN = {"lerobot-policy-obsbench"}
# spunet34 on a GPU: spconv's CUDA build instead of the CPU one this venv has (pyproject's `cuda` extra), with what
# it imports that the image lacks.
SPCONV_CUDA = {"spconv": "spconv-cu126", "cumm": "cumm-cu126"}
SPCONV_MODULES = ("spconv.pytorch",)
# PyPI's wheel tags for CPython 3.12 on x86-64 Linux, newest glibc first.
PLATFORMS = [f"manylinux_2_{n}_x86_64" for n in (39, 35, 34, 31, 28, 27, 24, 17)] + [
    "manylinux2014_x86_64",
    "manylinux1_x86_64",
]
# The device tool's Vulkan loader packages: the loader, and the GL dispatch libraries NVIDIA's ICD links against.
VULKAN_DEBS = ("libvulkan1", "libegl1", "libglvnd0", "libopengl0", "libgl1", "libglx0", "libgles2")


@dataclass(frozen=True)
class Trim:
    """Files of a wheel left out: under `drop` (globs) unless also under `keep`; Python code is always kept."""

    drop: tuple[str, ...]
    keep: tuple[str, ...] = ()
    why: str = ""

    def drops(self, name: str) -> bool:
        if name.endswith(".py") or ".dist-info/" in name:
            return False
        return _matches(name, self.drop) and not _matches(name, self.keep)


def _matches(name: str, patterns: tuple[str, ...]) -> bool:
    return any(fnmatch.fnmatch(name, pattern) for pattern in patterns)


TRIMS = {
    # the check's task (PushCubeWide-v1) loads the Panda arm (panda_v2, its meshes) and the table scene
    "mani-skill": Trim(
        drop=(
            "mani_skill/assets/robots/*",
            "mani_skill/assets/environment_maps/*",
            "mani_skill/assets/maniskill2-scene-2.glb",
            "mani_skill/utils/scene_builder/*",
        ),
        keep=(
            "mani_skill/assets/robots/panda/panda_v2.*",
            "mani_skill/assets/robots/panda/franka_description/*",
            "mani_skill/utils/scene_builder/table/*",
        ),
        why="code and the assets of PushCubeWide-v1 (Panda arm, table)",
    ),
    "sapien": Trim(
        drop=("sapien/include/*", "sapien/sensor/assets/*"),
        why="without the C++ headers and the stereo depth sensor's projector patterns",
    ),
}


@dataclass
class Item:
    """One file of the bundle."""

    name: str
    kind: str  # wheel, deb, tar (unpacked into the stash), library (copied to `dest`)
    path: Path
    note: str = ""
    dest: str = ""
    pieces: list[dict] = field(default_factory=list)

    @property
    def size(self) -> int:
        return self.path.stat().st_size


def normalise(name: str) -> str:
    return name.lower().replace("_", "-").replace(".", "-")


def needed_distributions(with_spconv: bool) -> dict[str, str]:
    """{distribution: version} this venv loads for the check's modules and the machine's image lacks."""
    modules = ["benchmarks.device_check", *(SPCONV_MODULES if with_spconv else ())]
    code = (
        "import importlib, json, sys\n"
        "import benchmarks.device_check as check\n"
        "check.import_modules()\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env)
    if done.returncode:
        raise SystemExit(f"device_bundle: importing the check's modules failed:\n{done.stderr[-3000:]}")
    import importlib.metadata as metadata

    providers = metadata.packages_distributions()
    image = {normalise(n) for n in IMAGE_PACKAGES}
    needed = {}
    for top in json.loads(done.stdout.splitlines()[-1]):
        dists = sorted({normalise(d) for d in providers.get(top, [])})
        if not dists or image & set(dists) or OWN & set(dists):
            continue
        dist = dists[0]
        name = SPCONV_CUDA.get(dist, dist) if with_spconv else dist
        needed[name] = metadata.version(dist)
    if with_spconv:
        needed.update(
            pccm=metadata.version("pccm"), ccimport=metadata.version("ccimport"), fire=metadata.version("fire")
        )
    return dict(sorted(needed.items()))


def fetch_wheel(name: str, version: str, cache: Path) -> Path:
    """The Python 3.12 x86-64 wheel of name==version: from the cache, PyPI, or built here when PyPI has none."""
    found = _cached(name, version, cache)
    if found:
        return found
    download = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:"]
    download += ["--python-version", "3.12", "--implementation", "cp", "--abi", "cp312", "--abi", "abi3"]
    download += [arg for p in PLATFORMS for arg in ("--platform", p)]
    done = subprocess.run([*download, "-d", str(cache), f"{name}=={version}"], capture_output=True, text=True)
    if done.returncode:  # no wheel on PyPI: build one (this machine must be the target's kind)
        if platform.machine() != "x86_64" or sys.version_info[:2] != (3, 12):
            raise SystemExit(f"device_bundle: {name}=={version} has no x86-64 wheel and this Python cannot build one")
        build = [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(cache), f"{name}=={version}"]
        built = subprocess.run(build, capture_output=True, text=True)
        if built.returncode:
            raise SystemExit(
                f"device_bundle: {name}=={version}: no wheel from PyPI ({done.stderr.strip()[-500:]}) and building "
                f"one failed ({built.stderr.strip()[-500:]})"
            )
    found = _cached(name, version, cache)
    if not found:
        raise SystemExit(f"device_bundle: no wheel of {name}=={version} after downloading")
    return found


def _cached(name: str, version: str, cache: Path) -> Path | None:
    for wheel in sorted(cache.glob("*.whl")):
        dist, wheel_version = wheel.name.split("-")[:2]
        if normalise(dist) == normalise(name) and wheel_version == version:
            return wheel
    return None


def _record_hash(data: bytes) -> str:
    return "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def trim_wheel(source: Path, target: Path, trim: Trim) -> dict:
    """`source` without the files `trim` drops, its RECORD rewritten for what is kept; what was dropped."""
    dropped, dropped_bytes = 0, 0
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as zout:
        record_name = next(n for n in zin.namelist() if n.endswith(".dist-info/RECORD"))
        lines = []
        for info in zin.infolist():
            if info.filename == record_name:
                continue
            if trim.drops(info.filename):
                dropped += 1
                dropped_bytes += info.file_size
                continue
            data = zin.read(info)
            zout.writestr(info, data)
            if not info.is_dir():
                lines.append(f"{info.filename},{_record_hash(data)},{len(data)}")
        zout.writestr(record_name, "\n".join([*lines, f"{record_name},,"]) + "\n")
    return {"dropped_files": dropped, "dropped_MiB": round(dropped_bytes / MIB, 1), "kept": trim.why}


def fetch_debs(cache: Path) -> list[Path]:
    """Debian's Vulkan loader packages for amd64, downloaded with apt (the device tool's recipe)."""
    debs = cache / "debs"
    found = sorted(debs.glob("*.deb"))
    if {p.name.split("_")[0] for p in found} >= set(VULKAN_DEBS):
        return found
    debs.mkdir(parents=True, exist_ok=True)
    lists = cache / "apt-lists"
    (lists / "partial").mkdir(parents=True, exist_ok=True)
    options = ["-oAPT::Architecture=amd64", "-oAPT::Architectures=amd64", f"-oDir::State::Lists={lists}"]
    subprocess.run(["apt-get", *options, "update", "-qq"], check=True)
    subprocess.run(["apt-get", *options, "download", "-qq", *VULKAN_DEBS], cwd=debs, check=True)
    return sorted(debs.glob("*.deb"))


def pack(items: list[Item], limit: int) -> list[list[dict]]:
    """Pieces of every item in parts of at most `limit` bytes: an item larger than that is cut into pieces of
    `limit` bytes (the last shorter); first-fit, largest first."""
    pieces = []
    for item in items:
        count = max(1, -(-item.size // limit))
        for index in range(count):
            size = min(limit, item.size - index * limit)
            name = item.name if count == 1 else f"{item.name}.{index:03d}"
            pieces.append({"item": item, "index": index, "name": name, "size": size})
    parts: list[list[dict]] = []
    for piece in sorted(pieces, key=lambda p: (-p["size"], p["name"])):
        home = next((part for part in parts if sum(p["size"] for p in part) + piece["size"] <= limit), None)
        if home is None:
            parts.append(home := [])
        home.append(piece)
    return parts


def write_parts(items: list[Item], out: Path, limit: int, missing: list[dict]) -> dict:
    """Write the parts under `out` (part-00, part-01, ...) and the manifest (in `out` and in every part)."""
    for old in out.glob("part-*"):
        shutil.rmtree(old)
    parts = pack(items, limit)
    for number, part in enumerate(parts):
        folder = out / f"part-{number:02d}"
        folder.mkdir(parents=True)
        for piece in part:
            item = piece["item"]
            with open(item.path, "rb") as source, open(folder / piece["name"], "wb") as target:
                source.seek(piece["index"] * limit)
                data = source.read(piece["size"])
                target.write(data)
            digest = hashlib.sha256(data).hexdigest()
            item.pieces.append(
                {
                    "part": folder.name,
                    "name": piece["name"],
                    "index": piece["index"],
                    "bytes": len(data),
                    "sha256": digest,
                }
            )
    manifest = {
        "built": datetime.now(UTC).isoformat(timespec="seconds"),
        "part_limit_MiB": round(limit / MIB, 3),
        "parts": [
            {"name": f"part-{n:02d}", "MiB": round(sum(p["size"] for p in part) / MIB, 2), "files": len(part)}
            for n, part in enumerate(parts)
        ],
        "items": [
            {
                "name": item.name,
                "kind": item.kind,
                "bytes": item.size,
                "sha256": hashlib.sha256(item.path.read_bytes()).hexdigest(),
                "pieces": sorted(item.pieces, key=lambda p: p["index"]),
                **({"dest": item.dest} if item.dest else {}),
                **({"note": item.note} if item.note else {}),
            }
            for item in sorted(items, key=lambda i: i.name)
        ],
        "missing": missing,
        "install": "python3 scripts/device_install.py .device_bundle/part-NN   # once per part",
    }
    text = json.dumps(manifest, indent=2) + "\n"
    (out / "manifest.json").write_text(text)
    for number in range(len(parts)):
        (out / f"part-{number:02d}" / "manifest.json").write_text(text)
    return manifest


def own_wheel(cache: Path) -> Item:
    """This plugin's wheel, built from the working tree: installed there, it gives LeRobot's plugin discovery and
    the plugin's version what they look up, while the working tree, first on PYTHONPATH, supplies the code."""
    folder = cache / "own"
    shutil.rmtree(folder, ignore_errors=True)
    build = [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", "-w", str(folder)]
    subprocess.run([*build, str(ROOT)], check=True, capture_output=True)
    wheel = next(folder.glob("*.whl"))
    return Item(wheel.name, "wheel", wheel, note="this plugin, built from the working tree")


def checkpoint_item(checkpoint: Path, cache: Path) -> Item:
    if not (checkpoint / "config.json").is_file():
        raise SystemExit(f"device_bundle: --checkpoint {checkpoint} has no config.json (a pretrained_model folder)")
    archive = cache / "checkpoint.tar"
    with tarfile.open(archive, "w") as tar:
        tar.add(checkpoint, arcname="checkpoint")
    return Item("checkpoint.tar", "tar", archive, note=f"from {checkpoint}")


def image_site(site: Path) -> int:
    """`site` filled with links to this venv's copies of the image's packages (those installed here): with the
    bundle's target before it on PYTHONPATH, a bare Python 3.12 sees what the GPU machine's Python will. The number
    of distributions linked."""
    import importlib.metadata as metadata

    image = {normalise(n) for n in IMAGE_PACKAGES}
    site.mkdir(parents=True, exist_ok=True)
    linked = 0
    for dist in metadata.distributions():
        if normalise(dist.metadata["Name"]) not in image:
            continue
        linked += 1
        base = Path(dist.locate_file(""))
        for entry in {Path(f).parts[0] for f in dist.files or [] if not str(f).startswith("..")}:
            link = site / entry
            if not link.exists() and (base / entry).exists():
                link.symlink_to(base / entry)
    return linked


def verify(out: Path, python: str) -> dict:
    """Install every part with scripts/device_install.py into a scratch target (Debian packages into a scratch
    root) and run the device check, tiny and on the CPU, with a bare `python` that sees only the image's packages
    (`image_site`) and the bundle: its JSON."""
    scratch = out / "verify"
    shutil.rmtree(scratch, ignore_errors=True)
    linked = image_site(scratch / "image-site")
    target, stash = scratch / "site", scratch / "stash"
    for part in sorted(out.glob("part-*")):
        install = [python, str(ROOT / "scripts" / "device_install.py"), str(part)]
        install += ["--target", str(target), "--stash", str(stash), "--root", str(scratch / "root")]
        subprocess.run(install, check=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(map(str, (ROOT, target, scratch / "image-site")))}
    check = [python, "-m", "benchmarks.device_check", "--device", "cpu", "--tiny", "--out", str(scratch / "check")]
    if (stash / "checkpoint").is_dir():
        check += ["--checkpoint", str(stash / "checkpoint")]
    subprocess.run(check, cwd=ROOT, env=env, check=True)
    result = json.loads((scratch / "check" / "device_check.json").read_text())
    print(f"verify: {linked} image distributions linked from this venv; stages ok: ", end="")
    print({name: stage["ok"] for name, stage in result["stages"].items()})
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=ROOT / ".device_bundle")
    parser.add_argument("--part-mib", type=float, default=56.0, help="largest part, MiB (at most 60)")
    parser.add_argument("--checkpoint", type=Path, help="the pretrained_model folder the check evaluates")
    parser.add_argument("--with-spconv", action="store_true", help="spconv's CUDA build, for SpUNet-34 (~93 MB)")
    parser.add_argument(
        "--verify",
        metavar="PYTHON",
        help="then install the parts into a scratch folder and run the device check (tiny, CPU) with this bare "
        "Python 3.12 seeing only the image's packages and the bundle",
    )
    args = parser.parse_args(argv)
    if not 0 < args.part_mib <= 60:
        parser.error(f"--part-mib must be in (0, 60]; got {args.part_mib}")
    cache = args.out / "cache"
    (cache / "trimmed").mkdir(parents=True, exist_ok=True)
    items, missing = [], []
    needed = needed_distributions(args.with_spconv)
    print(f"carrying {len(needed)} distributions: {', '.join(f'{n}=={v}' for n, v in needed.items())}")
    for name, version in needed.items():
        wheel = fetch_wheel(name, version, cache)
        if name in TRIMS:
            trimmed = cache / "trimmed" / wheel.name
            note = trim_wheel(wheel, trimmed, TRIMS[name])
            items.append(Item(wheel.name, "wheel", trimmed, note=f"trimmed: {note}"))
        else:
            items.append(Item(wheel.name, "wheel", wheel))
    items.append(own_wheel(cache))
    items += [Item(deb.name, "deb", deb) for deb in fetch_debs(cache)]
    if args.checkpoint:
        items.append(checkpoint_item(args.checkpoint, cache))
    from lerobot_obsbench.envs.maniskill import physx_gpu_library

    library = physx_gpu_library()
    if library.is_file():
        items.append(Item(library.name, "library", library, dest=str(library.relative_to(Path.home()))))
    else:
        missing.append(
            {
                "what": f"SAPIEN's GPU PhysX library (~/{library.relative_to(Path.home())})",
                "why": "SAPIEN downloads it from GitHub at the first GPU simulation; this machine has none to carry "
                "(run one GPU simulation where GitHub is reachable, or unzip the release's linux-so.zip there)",
            }
        )
    manifest = write_parts(items, args.out, int(args.part_mib * MIB), missing)
    for part in manifest["parts"]:
        print(f"{part['name']}: {part['MiB']} MiB, {part['files']} files")
    for gap in missing:
        print(f"missing: {gap['what']}: {gap['why']}")
    print(f"manifest: {args.out / 'manifest.json'}")
    if args.verify:
        verify(args.out, args.verify)


if __name__ == "__main__":
    main()
