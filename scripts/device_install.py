"""Install one part of the device bundle (scripts/device_bundle.py) on the GPU machine; standard library only.

    python3 scripts/device_install.py .device_bundle/part-00 [--target /tmp/obsbench-site]
        [--stash /tmp/obsbench-bundle] [--root /]

The part's pieces are copied into the stash, which outlives the call on a machine that stays warm between calls.
Every file whose pieces have all arrived is joined and checked against the manifest's SHA-256, then: a wheel is
installed into --target by pip (no index, no dependencies; put --target first on PYTHONPATH), a Debian package
unpacked into --root (the Vulkan loader), a tar unpacked into the stash (the checkpoint: STASH/checkpoint), a
library copied to its place under the home folder (SAPIEN's GPU PhysX). Prints what was installed and which parts
are still to come; exits 1 on a corrupt file, 2 on a part that is not one.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path


def load_state(stash: Path) -> dict:
    path = stash / "installed.json"
    return json.loads(path.read_text()) if path.is_file() else {"installed": []}


def joined(item: dict, stash: Path) -> Path | None:
    """The item's file in the stash, joined from its pieces, or None while a piece is missing."""
    paths = [stash / "pieces" / piece["name"] for piece in item["pieces"]]
    if not all(path.is_file() for path in paths):
        return None
    target = stash / "files" / item["name"]
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target, "wb") as out:
        for path in paths:
            with open(path, "rb") as piece:
                shutil.copyfileobj(piece, out)
    digest = hashlib.sha256(target.read_bytes()).hexdigest()
    if digest != item["sha256"]:
        target.unlink()
        raise SystemExit(f"device_install: {item['name']} is corrupt (sha256 {digest}, manifest {item['sha256']})")
    return target


def install(files: list[tuple[dict, Path]], target: Path, stash: Path, root: Path) -> None:
    wheels = [str(path) for item, path in files if item["kind"] == "wheel"]
    if wheels:
        pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-index", "--no-deps", "--no-compile"]
        pip += ["--no-cache-dir", "--upgrade", "--target", str(target)]
        subprocess.run([*pip, *wheels], check=True)
    debs = [path for item, path in files if item["kind"] == "deb"]
    for deb in debs:
        subprocess.run(["dpkg", "-x", str(deb), str(root)], check=True)
    if debs and root == Path("/"):
        subprocess.run(["ldconfig"], check=True)
    for item, path in files:
        if item["kind"] == "tar":
            with tarfile.open(path) as tar:
                tar.extractall(stash, filter="data")
        elif item["kind"] == "library":
            destination = Path.home() / item["dest"]
            destination.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, destination)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("part", type=Path, help="a part folder of the bundle (part-NN, with its manifest.json)")
    parser.add_argument("--target", type=Path, default=Path("/tmp/obsbench-site"), help="where wheels go")
    parser.add_argument("--stash", type=Path, default=Path("/tmp/obsbench-bundle"), help="pieces, state, checkpoint")
    parser.add_argument("--root", type=Path, default=Path("/"), help="where Debian packages are unpacked")
    args = parser.parse_args(argv)
    manifest_path = args.part / "manifest.json"
    if not manifest_path.is_file():
        parser.error(f"{args.part}: no manifest.json (give a part folder written by scripts/device_bundle.py)")
    manifest = json.loads(manifest_path.read_text())
    (args.stash / "pieces").mkdir(parents=True, exist_ok=True)
    state = load_state(args.stash)
    for item in manifest["items"]:
        for piece in item["pieces"]:
            if piece["part"] == args.part.name:
                shutil.copyfile(args.part / piece["name"], args.stash / "pieces" / piece["name"])
    ready = []
    for item in manifest["items"]:
        if item["name"] not in state["installed"] and (path := joined(item, args.stash)) is not None:
            ready.append((item, path))
    install(ready, args.target, args.stash, args.root)
    state["installed"] += [item["name"] for item, _ in ready]
    (args.stash / "installed.json").write_text(json.dumps(state, indent=2) + "\n")
    waiting = sorted(
        {
            piece["part"]
            for item in manifest["items"]
            if item["name"] not in state["installed"]
            for piece in item["pieces"]
            if not (args.stash / "pieces" / piece["name"]).is_file()
        }
    )
    print(f"device_install: {args.part.name}: installed {len(ready)} ({', '.join(i['name'] for i, _ in ready)})")
    print(f"device_install: {len(state['installed'])} of {len(manifest['items'])} files in place", end="")
    print(f"; still to come: {', '.join(waiting)}" if waiting else "; the bundle is complete")


if __name__ == "__main__":
    main()
