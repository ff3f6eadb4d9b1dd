"""A local stand-in for the Hugging Face Hub (this machine cannot reach it).

Uploads go through the real `HfApi` calls the code makes; the stand-in replaces only the network side of
`create_repo`, `upload_folder`, `upload_file`, the tag calls and the card's YAML check: the files land in
`root/remote/<type>s/<repo>` and are also laid out as a downloaded snapshot in a Hugging Face cache
(`root/cache`: `<type>s--ORG--NAME/refs/main` + `snapshots/<commit>/...`). A new process with
`HF_HUB_CACHE=root/cache` and `HF_HUB_OFFLINE=1` then pulls them through huggingface_hub's own offline
resolution, as a machine that downloaded them would.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path
from types import SimpleNamespace

from huggingface_hub import HfApi, repocard
from huggingface_hub.utils import filter_repo_objects


class LocalHub:
    def __init__(self, root: Path):
        self.root = Path(root)
        self.cache = self.root / "cache"
        self.uploads: list[dict] = []

    def remote(self, repo_id: str, repo_type: str = "model") -> Path:
        return self.root / "remote" / f"{repo_type}s" / repo_id

    def env(self) -> dict[str, str]:
        """Environment of a process that pulls from this stand-in."""
        return {"HF_HUB_CACHE": str(self.cache), "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}

    def _publish(self, repo_id: str, repo_type: str) -> None:
        """Lay the remote repo out as a cached snapshot of a new commit."""
        remote = self.remote(repo_id, repo_type)
        files = sorted(p for p in remote.rglob("*") if p.is_file())
        digest = hashlib.sha1()
        for f in files:
            digest.update(str(f.relative_to(remote)).encode() + f.read_bytes())
        commit = digest.hexdigest()
        repo_cache = self.cache / f"{repo_type}s--{repo_id.replace('/', '--')}"
        snapshot = repo_cache / "snapshots" / commit
        shutil.rmtree(snapshot, ignore_errors=True)
        shutil.copytree(remote, snapshot)
        (repo_cache / "refs").mkdir(parents=True, exist_ok=True)
        (repo_cache / "refs" / "main").write_text(commit)

    # ---- the HfApi methods the code calls -------------------------------------------------------------

    def create_repo(self, _api, repo_id, *, repo_type=None, exist_ok=False, private=None, **_):
        self.remote(repo_id, repo_type or "model").mkdir(parents=True, exist_ok=True)
        return SimpleNamespace(repo_id=repo_id, url=f"local-hub://{repo_id}")

    def upload_folder(
        self,
        _api,
        *,
        repo_id,
        folder_path,
        repo_type=None,
        allow_patterns=None,
        ignore_patterns=None,
        path_in_repo=None,
        **_,
    ):
        repo_type = repo_type or "model"
        folder = Path(folder_path)
        names = [str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()]
        kept = list(filter_repo_objects(names, allow_patterns=allow_patterns, ignore_patterns=ignore_patterns))
        target = self.remote(repo_id, repo_type) / (path_in_repo or "")
        for name in kept:
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(folder / name, target / name)
        self.uploads.append({"repo_id": repo_id, "repo_type": repo_type, "files": sorted(kept)})
        self._publish(repo_id, repo_type)
        return SimpleNamespace(repo_url=SimpleNamespace(url=f"local-hub://{repo_id}"), oid="0")

    def upload_file(self, _api, *, path_or_fileobj, path_in_repo, repo_id, repo_type=None, **_):
        repo_type = repo_type or "model"
        target = self.remote(repo_id, repo_type) / path_in_repo
        target.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(path_or_fileobj, (str, Path)):
            shutil.copy2(path_or_fileobj, target)
        else:
            target.write_bytes(path_or_fileobj if isinstance(path_or_fileobj, bytes) else path_or_fileobj.read())
        self.uploads.append({"repo_id": repo_id, "repo_type": repo_type, "files": [path_in_repo]})
        self._publish(repo_id, repo_type)
        return f"local-hub://{repo_id}/{path_in_repo}"

    def tag(self, _api, *args, **kwargs):  # create_tag / delete_tag: revisions are not modelled
        return None

    def install(self, monkeypatch) -> LocalHub:
        for name in ("create_repo", "upload_folder", "upload_file"):
            method = getattr(self, name)
            monkeypatch.setattr(HfApi, name, lambda api, *a, _m=method, **k: _m(api, *a, **k))
        for name in ("create_tag", "delete_tag"):
            monkeypatch.setattr(HfApi, name, self.tag)
        # model/dataset cards push through the module-level function, bound when huggingface_hub was imported
        monkeypatch.setattr(repocard, "upload_file", lambda *a, **k: self.upload_file(None, *a, **k))
        monkeypatch.setattr(repocard.RepoCard, "validate", lambda card, repo_type=None: None)  # the Hub's YAML check
        return self
