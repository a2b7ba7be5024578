"""Cache keys, manifests and atomic publish of a stage's folder (docs/architecture.md).

The key is chained (a digest of the stage's name, version, resolved config and its upstream
keys), so the whole plan is known before anything runs.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

from pydantic import BaseModel

MANIFEST = "manifest.json"
#: freshness()'s reason when the key differs; explain_change() says which setting or input.
KEY_CHANGED = "config or upstream changed"


def canonical_json(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)


def digest_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def digest_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def digest_path(path: Path) -> str:
    """Content digest of a file, or of every file in a folder (names and contents)."""
    path = Path(path)
    if path.is_file():
        return digest_file(path)
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode())
        h.update(digest_file(f).encode())
    return h.hexdigest()


def stage_key(
    name: str, version: int, config: dict, upstream_keys: dict[str, str], input_digest: str | None
) -> str:
    return digest_text(
        canonical_json(
            {
                "stage": name,
                "version": version,
                "config": config,
                "upstream": upstream_keys,
                "input": input_digest,
            }
        )
    )


class FileEntry(BaseModel):
    size: int
    sha256: str


class Manifest(BaseModel):
    """Written last into a stage folder: what produced it and what it holds."""

    stage: str
    key: str
    version: int
    config: dict
    upstream: dict[str, str]
    started: float
    finished: float
    wall_s: float
    #: CPU seconds of the process while the stage ran, every thread (None: not measured)
    cpu_s: float | None = None
    peak_rss_mb: float
    summary: dict
    files: dict[str, FileEntry]

    @classmethod
    def load(cls, folder: Path) -> Manifest | None:
        path = folder / MANIFEST
        if not path.is_file():
            return None
        try:
            return cls.model_validate_json(path.read_text())
        except ValueError:
            return None


def list_files(folder: Path) -> dict[str, FileEntry]:
    out: dict[str, FileEntry] = {}
    for f in sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST):
        out[str(f.relative_to(folder))] = FileEntry(size=f.stat().st_size, sha256=digest_file(f))
    return out


def freshness(folder: Path, key: str, verify_digests: bool = False) -> tuple[bool, str]:
    """(fresh, reason). Fresh = manifest key matches and every listed file is intact."""
    if not folder.is_dir():
        return False, "missing"
    manifest = Manifest.load(folder)
    if manifest is None:
        return False, "no manifest"
    if manifest.key != key:
        return False, KEY_CHANGED
    for rel, entry in manifest.files.items():
        f = folder / rel
        if not f.is_file():
            return False, f"file missing: {rel}"
        if f.stat().st_size != entry.size:
            return False, f"file changed: {rel}"
        if verify_digests and digest_file(f) != entry.sha256:
            return False, f"file changed: {rel}"
    return True, "fresh"


def flatten(data: dict, prefix: str = "") -> dict[str, Any]:
    """Nested settings as dotted keys (`train.steps`), so a change can be named by its key."""
    out: dict[str, Any] = {}
    for k, v in data.items():
        if isinstance(v, dict) and v:
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def config_change(manifest: Manifest, version: int, config: dict, limit: int = 3) -> str | None:
    """The stage's own change behind a new key, in the user's words (`train.steps 600 -> 1500`,
    or a new code version); None when its config and version are those of its manifest."""
    if manifest.version != version:
        return f"{manifest.stage} code changed (version {manifest.version} -> {version})"
    old, new = flatten(manifest.config), flatten(config)
    keys = sorted(old.keys() | new.keys())
    changed = [k for k in keys if old.get(k, _ABSENT) != new.get(k, _ABSENT)]
    if not changed:
        return None
    parts = [f"{manifest.stage}.{k} {_show(old, k)} -> {_show(new, k)}" for k in changed[:limit]]
    more = f" (+{len(changed) - limit} more)" if len(changed) > limit else ""
    return ", ".join(parts) + more


_ABSENT = object()


def _show(values: dict[str, Any], key: str, width: int = 40) -> str:
    if key not in values:
        return "(unset)"
    text = json.dumps(values[key], default=str)
    return text if len(text) <= width else text[: width - 1] + "…"


def temp_dir_for(final: Path, key: str) -> Path:
    """The temporary folder is named after the key, so a resumable stage finds its checkpoint."""
    return final.parent / f".{final.name}.tmp-{key[:8]}"


def stale_temps(final: Path, keep: Path | None) -> list[Path]:
    return [p for p in final.parent.glob(f".{final.name}.tmp-*") if p != keep]


def publish(tmp: Path, final: Path, manifest: Manifest) -> None:
    """Write the manifest last, then swap the folder into place with renames."""
    (tmp / MANIFEST).write_text(manifest.model_dump_json(indent=2))
    _fsync_dir(tmp)
    old = None
    if final.exists():
        old = final.parent / f".{final.name}.old-{int(time.time() * 1e6)}"
        os.replace(final, old)
    os.replace(tmp, final)
    _fsync_dir(final.parent)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
