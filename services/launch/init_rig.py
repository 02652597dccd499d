"""`nod up RIG.toml --init-rig DIR`: copy a rig file together with the files it names.

A rig file's relative paths are relative to the file itself, so a rig file copied alone (the
example, `deploy/rig.example.toml`, to `/etc/nod/rig.toml`) names files that are not beside it.
This writes DIR/rig.toml as it is — comments and all — and copies every file it names by a
relative path (the params file, the arm and eyes files, trims, a vision calibration or video
file) to the same relative place under DIR, so the copy means what the original did. Absolute
paths and folders (rig.tls, state_dir) are left as they are. Nothing is overwritten: an existing
DIR/rig.toml is refused, an existing named file kept.

Why a copy and not paths into the checkout: the copied files are the lab's own from now on
(calibrated poses, trims, the study's parameters), kept beside the rig file in /etc/nod, where
an update of the checkout (`deploy/setup-host` syncs /opt/nod-hri with --delete) never touches
them, and the rig file keeps working wherever the folder is moved.
"""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path

from services.core.rigfile import FILE_KEYS, FOLDER_KEYS, RigFileError, is_file_source, load_rig

RIG_NAME = "rig.toml"


def named_files(doc: dict) -> list[tuple[str, str]]:
    """(key, path as written) of every file a parsed rig file names."""
    out = [(f"{s}.{k}", doc[s][k]) for s, k in FILE_KEYS if k in doc.get(s, {})]
    source = doc.get("vision", {}).get("source")
    if isinstance(source, str) and is_file_source(source):
        out.append(("vision.source", source))
    return out


def init_rig(source: Path, folder: Path) -> list[str]:
    """Copy `source` to folder/rig.toml with its relative files; what was done, one line each.

    RigFileError (one line) if the source is not a valid rig file, folder/rig.toml exists, or a
    relative path leads out of the source's folder (it would land outside DIR).
    """
    load_rig(source)  # a broken rig file is not copied
    text = source.read_text()
    doc = tomllib.loads(text)
    target = folder / RIG_NAME
    if target.exists():
        raise RigFileError(f"{target} exists: not overwritten (edit it, or choose another DIR)")
    copies: list[tuple[str, Path, Path]] = []
    for key, value in named_files(doc):
        rel = Path(value).expanduser()
        if rel.is_absolute():
            continue
        if ".." in rel.parts:
            raise RigFileError(f"{source}: {key}: {value!r} leads out of the rig file's folder: "
                               "make it absolute, or move the file beside the rig file")
        copies.append((key, source.parent / rel, folder / rel))
    lines: list[str] = []
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for key, src, dst in copies:
            if dst.exists():
                lines.append(f"kept {dst} ({key}: it was there already)")
            elif not src.is_file():
                lines.append(f"not copied: {key} = {src} does not exist (write it there later)")
            else:
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src, dst)
                lines.append(f"copied {src} -> {dst} ({key})")
        target.write_text(text)
    except OSError as exc:
        raise RigFileError(f"cannot write to {folder}: {exc.strerror or exc}") from None
    for section, key in FOLDER_KEYS:
        value = doc.get(section, {}).get(key)
        if isinstance(value, str) and not Path(value).expanduser().is_absolute():
            lines.append(f"note: {section}.{key} = {value!r} is now relative to {folder}")
    lines.insert(0, f"wrote {target} (from {source})")
    lines.append(f"next: edit {target} (hosts, ports, files), then check it with "
                 f"`nod up {target} --dry-run`")
    return lines
