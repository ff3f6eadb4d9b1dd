"""Install one part of the device bundle (scripts/device_bundle.py) on the GPU node; standard library only.

    python3 scripts/device_install.py .device_bundle/part-00 [--target /tmp/obsbench-site]
        [--stash /tmp/obsbench-bundle] [--root /]

It runs with the node's bare Python before anything of the bundle is installed, so it imports nothing of the
plugin and checks what it is given itself. Each piece of the part is checked against its size and SHA-256 in the
manifest, then copied into the stash, which collects the parts as they arrive one at a time. The stash
holds one bundle: a part of another bundle (one whose manifest lists other files or other contents) is refused,
naming the files that differ. Every file whose pieces have all arrived is joined and checked against the manifest's
SHA-256, then: a wheel is installed into --target by pip (no index, no dependencies; put --target first on
PYTHONPATH), a Debian package unpacked into --root (the Vulkan loader), a tar unpacked into the stash (the
checkpoint: STASH/checkpoint), a library copied to its place under the home folder (SAPIEN's GPU PhysX). Prints
what was installed and which parts are still to come. A folder that is not a part, a missing or damaged manifest
or piece, or a part of another bundle is refused in one line with the fix, exit code 2, before anything is copied.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

KINDS = ("wheel", "deb", "tar", "library")
STATE = "installed.json"
SHOWN = 3  # files named in a refusal before "and N more"


class Refusal(Exception):
    """Input this installer will not use; the message names the part or file and the fix."""


def _is_count(value) -> bool:
    """A whole number >= 0, never a bool: the manifest's sizes, checked as the plugin's numeric rule would."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _is_sha256(value) -> bool:
    return isinstance(value, str) and len(value) == 64 and all(c in "0123456789abcdef" for c in value)


def _is_file_name(value) -> bool:
    """A plain file name: pieces and files are written under the stash by these names."""
    return isinstance(value, str) and value not in ("", ".", "..") and not {"/", "\\", "\0"} & set(value)


def _sha256(path: Path) -> str:
    with open(path, "rb") as stream:
        return hashlib.file_digest(stream, "sha256").hexdigest()


def _names(names: list[str]) -> str:
    return ", ".join(names[:SHOWN]) + (f" and {len(names) - SHOWN} more" if len(names) > SHOWN else "")


def manifest_problem(manifest) -> str | None:
    """What makes `manifest` unusable (None when nothing does): every file with its kind, size and SHA-256, and
    pieces that name their part and carry their own size and SHA-256, adding up to the file."""
    if not isinstance(manifest, dict) or not all(isinstance(manifest.get(key), list) for key in ("parts", "items")):
        return "no list of parts and of files"
    parts = [part.get("name") if isinstance(part, dict) else None for part in manifest["parts"]]
    if not all(_is_file_name(name) for name in parts):
        return "a part without its folder name"
    for item in manifest["items"]:
        name = item.get("name") if isinstance(item, dict) else None
        if not _is_file_name(name):
            return "a file without its name"
        if item.get("kind") not in KINDS or not _is_sha256(item.get("sha256")) or not _is_count(item.get("bytes")):
            return f"{name}: no kind ({', '.join(KINDS)}), size and sha256"
        if item["kind"] == "library" and not isinstance(item.get("dest"), str):
            return f"{name}: a library without its destination"
        pieces = item.get("pieces")
        if not isinstance(pieces, list) or not pieces:
            return f"{name}: no pieces"
        for piece in pieces:
            if not isinstance(piece, dict) or not _is_file_name(piece.get("name")) or piece.get("part") not in parts:
                return f"{name}: a piece without its file name and part"
            if not _is_sha256(piece.get("sha256")) or not _is_count(piece.get("bytes")):
                return f"{name}: piece {piece['name']} has no size and sha256 (a bundle of an older device_bundle.py)"
        if sum(piece["bytes"] for piece in pieces) != item["bytes"]:
            return f"{name}: its pieces do not add up to its size"
    return None


def copy_again(part: Path) -> str:
    return f"copy {part.name} again from the bundle's folder (.device_bundle/{part.name})"


def read_manifest(part: Path) -> dict:
    path = part / "manifest.json"
    if not path.is_file():
        raise Refusal(f"{part}: no manifest.json (give a part folder written by scripts/device_bundle.py)")
    try:
        manifest = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise Refusal(f"{path} is truncated or damaged ({err}); {copy_again(part)}") from None
    problem = manifest_problem(manifest)
    if problem:
        raise Refusal(
            f"{path} is not a manifest of scripts/device_bundle.py as this installer reads it ({problem}); rebuild "
            "the bundle with scripts/device_bundle.py"
        )
    parts = [entry["name"] for entry in manifest["parts"]]
    if part.name not in parts:
        raise Refusal(
            f"{part}: {part.name} is not one of its manifest's parts ({', '.join(parts)}); keep the part folders' "
            "names as scripts/device_bundle.py wrote them"
        )
    return manifest


def bundle_of(manifest: dict) -> dict:
    """The bundle a manifest belongs to: an id from its files' and pieces' contents (the same in every part of one
    bundle), when it was built, and each file's SHA-256."""
    content = json.dumps(manifest["items"], sort_keys=True).encode()
    return {
        "id": hashlib.sha256(content).hexdigest()[:12],
        "built": manifest.get("built"),
        "files": {item["name"]: item["sha256"] for item in manifest["items"]},
    }


def load_state(stash: Path) -> dict | None:
    """The stash's record of its bundle and the files installed from it; None for a new stash."""
    path = stash / STATE
    if not path.exists():
        return None
    try:
        state = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        state = None
    bundle = state.get("bundle") if isinstance(state, dict) else None
    known = isinstance(bundle, dict) and isinstance(bundle.get("id"), str) and isinstance(bundle.get("files"), dict)
    if not (known and isinstance(state.get("installed"), dict)):
        raise Refusal(
            f"{path} is damaged or was written by an older device_install.py; delete the stash (rm -rf {stash}) and "
            "install each part of the bundle again"
        )
    return state


def check_same_bundle(part: Path, bundle: dict, stashed: dict, stash: Path) -> None:
    """Refuse a part of another bundle than the one in the stash, saying which files differ."""
    if bundle["id"] == stashed["id"]:
        return
    here, there = bundle["files"], stashed["files"]
    changed = sorted(name for name in here.keys() & there.keys() if here[name] != there[name])
    differences = [
        f"{_names(names)} {what}"
        for names, what in (
            (changed, "differs" if len(changed) == 1 else "differ"),
            (sorted(here.keys() - there.keys()), "only in this bundle"),
            (sorted(there.keys() - here.keys()), "only in the stash's"),
        )
        if names
    ]

    def named(entry: dict) -> str:
        return f"bundle {entry['id']}" + (f", built {entry['built']}" if entry.get("built") else "")

    raise Refusal(
        f"{part.name} belongs to another bundle ({named(bundle)}) than the one {stash} holds ({named(stashed)}): "
        f"{'; '.join(differences) or 'the same files, cut into other pieces'}; to install this bundle, delete the "
        f"stash (rm -rf {stash}) and install each of its parts, or give --stash a new folder"
    )


def checked_pieces(part: Path, manifest: dict) -> list[dict]:
    """The pieces this part carries, each checked against its size and SHA-256 in the manifest."""
    pieces = [piece for item in manifest["items"] for piece in item["pieces"] if piece["part"] == part.name]
    for piece in pieces:
        path = part / piece["name"]
        if not path.is_file():
            raise Refusal(
                f"{part.name} lacks {piece['name']}, one of the pieces its manifest lists; {copy_again(part)}"
            )
        size, digest = path.stat().st_size, _sha256(path)
        if (size, digest) != (piece["bytes"], piece["sha256"]):
            raise Refusal(
                f"{part.name}/{piece['name']} is not the piece its manifest lists ({size} bytes, sha256 {digest[:16]}; "
                f"listed: {piece['bytes']} bytes, sha256 {piece['sha256'][:16]}): it was damaged or comes from "
                f"another build; {copy_again(part)}"
            )
    return pieces


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
    digest = _sha256(target)
    if digest != item["sha256"]:
        target.unlink()
        raise Refusal(
            f"{item['name']}, joined from the pieces in {stash}, has sha256 {digest[:16]}, not the manifest's "
            f"{item['sha256'][:16]}: the stash was changed; delete it (rm -rf {stash}) and install each part again"
        )
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


def install_part(part: Path, target: Path, stash: Path, root: Path) -> None:
    manifest = read_manifest(part)
    bundle = bundle_of(manifest)
    state = load_state(stash) or {"bundle": bundle, "installed": {}}
    check_same_bundle(part, bundle, state["bundle"], stash)
    pieces = checked_pieces(part, manifest)
    (stash / "pieces").mkdir(parents=True, exist_ok=True)
    for piece in pieces:
        shutil.copyfile(part / piece["name"], stash / "pieces" / piece["name"])
    ready = []
    for item in manifest["items"]:
        if state["installed"].get(item["name"]) != item["sha256"] and (path := joined(item, stash)) is not None:
            ready.append((item, path))
    install(ready, target, stash, root)
    state["installed"].update({item["name"]: item["sha256"] for item, _ in ready})
    temporary = stash / f".{STATE}.tmp"  # renamed into place: a call stopped mid-write leaves the last whole state
    temporary.write_text(json.dumps(state, indent=2) + "\n")
    os.replace(temporary, stash / STATE)
    waiting = sorted(
        {
            piece["part"]
            for item in manifest["items"]
            if item["name"] not in state["installed"]
            for piece in item["pieces"]
            if not (stash / "pieces" / piece["name"]).is_file()
        }
    )
    print(f"device_install: {part.name}: installed {len(ready)} ({', '.join(i['name'] for i, _ in ready)})")
    print(f"device_install: {len(state['installed'])} of {len(manifest['items'])} files in place", end="")
    print(f"; still to come: {', '.join(waiting)}" if waiting else "; the bundle is complete")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("part", type=Path, help="a part folder of the bundle (part-NN, with its manifest.json)")
    parser.add_argument("--target", type=Path, default=Path("/tmp/obsbench-site"), help="where wheels go")
    parser.add_argument("--stash", type=Path, default=Path("/tmp/obsbench-bundle"), help="pieces, state, checkpoint")
    parser.add_argument("--root", type=Path, default=Path("/"), help="where Debian packages are unpacked")
    args = parser.parse_args(argv)
    try:
        install_part(args.part, args.target, args.stash, args.root)
    except Refusal as refusal:
        print(f"device_install: {refusal}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
