"""A session's provenance: which code, parameters, rig, study and hosts produced it.

`Provenance` is one conductor run of a session (a resumed session has one per run): the code's
version and a digest of its sources (`sources_digest`: SHA-256 over every `.py` file of the
`services` package, by path, in sorted order — computed once per process), the effective
parameters' hash (`services.core.config.params_hash`, of the values: the rig's services send
the same one in their heartbeats) and the SHA-256 of each file given — params, rig file, and a
policy file (optional: no service takes one yet; the field is kept for the day one does) —, the
study file's name, consent-form version, allocation seed (its counterbalance seed) and
pre-registration id, the host of each service heard on `rig/status` during the run
(`HostsSeen`), and the recording `--record` made of it with the file's SHA-256 at its finish.

The store keeps it (`services.store.provenance`), `nod report` shows it, `nod export` writes
it (provenance.csv), `nod record` writes what was known at the start as the recording's
`provenance` metadata record (`metadata`), and `nod analyze study` refuses to pool sessions
whose parameters differ (`mixed_params`).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

PROVENANCE_METADATA = "provenance"  # the name of the recording's metadata record
STUDY_TEXT_FIELDS = ("consent_version", "preregistration")  # optional [study] strings
CHUNK = 1 << 20
SHOWN_SESSIONS = 3  # sessions named per parameter set in `mixed_params`' line


@dataclass(frozen=True, slots=True)
class StudyFacts:
    """What a session's provenance takes from its study file."""

    file: str  # absolute path
    sha256: str
    name: str
    consent_version: str | None
    allocation_seed: int | None  # the roster's shuffle seed ([counterbalance] seed)
    preregistration: str | None


@dataclass(frozen=True, slots=True)
class Provenance:
    """One conductor run of a session: its code, inputs and hosts (module doc)."""

    version: str
    sources_sha256: str
    params_hash: str
    params_file: str | None = None
    params_sha256: str | None = None
    rig_file: str | None = None
    rig_sha256: str | None = None
    policy_file: str | None = None
    policy_sha256: str | None = None
    study_file: str | None = None
    study_sha256: str | None = None
    study_name: str | None = None
    consent_version: str | None = None
    allocation_seed: int | None = None
    preregistration: str | None = None
    hosts: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # service -> hosts
    recording_file: str | None = None
    recording_sha256: str | None = None

    def as_dict(self) -> dict[str, Any]:
        """Every field, hosts as {service: [host, …]} (JSON-ready)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["hosts"] = {s: list(h) for s, h in sorted(self.hosts.items())}
        return out


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, hex (OSError if it cannot be read)."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as fh:
        while block := fh.read(CHUNK):
            digest.update(block)
    return digest.hexdigest()


def tree_digest(root: Path) -> str:
    """SHA-256 over every `.py` file under `root`, in sorted path order.

    Each file adds its path (relative, POSIX) and its bytes' SHA-256: the same tree gives the
    same digest on any machine.
    """
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py"), key=lambda p: p.relative_to(root).as_posix()):
        rel = path.relative_to(root).as_posix()
        digest.update(f"{rel}\0{file_sha256(path)}\n".encode())
    return digest.hexdigest()


@functools.cache
def sources_digest() -> str:
    """The digest of this process's `services` package (`tree_digest`), computed once."""
    return tree_digest(Path(__file__).resolve().parent.parent)


def study_text(table: Mapping[str, Any], key: str) -> str | None:
    """An optional text field of a study file's [study] table: None when absent.

    ValueError if it is there but not a non-empty string (the study file's own check).
    """
    value = table.get(key)
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"[study] {key} must be a non-empty string, got {value!r}")
    return value.strip()


def study_facts(path: Path) -> StudyFacts:
    """The provenance of a study file (ValueError, one line, if it cannot be read as one)."""
    try:
        raw = path.read_bytes()
        data = tomllib.loads(raw.decode("utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"cannot read the study file {path}: {exc}") from None
    study, cb = data.get("study"), data.get("counterbalance", {})
    if not isinstance(study, dict) or not isinstance(study.get("name"), str):
        raise ValueError(f"{path} is not a study file: no [study] name")
    seed = cb.get("seed") if isinstance(cb, dict) else None
    try:
        texts = [study_text(study, k) for k in STUDY_TEXT_FIELDS]
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return StudyFacts(
        str(path.resolve()), hashlib.sha256(raw).hexdigest(), study["name"], texts[0],
        seed if isinstance(seed, int) and not isinstance(seed, bool) else None, texts[1],
    )


def make_provenance(
    version: str,
    params_hash: str,
    params: Path | None = None,
    rig: Path | None = None,
    policy: Path | None = None,
    study: Path | None = None,
) -> Provenance:
    """A run's provenance at its start (its hosts and recording come at its end).

    ValueError (one line) for a file given that cannot be read.
    """
    params_file, params_sha256 = _digest("params", params)
    rig_file, rig_sha256 = _digest("rig", rig)
    policy_file, policy_sha256 = _digest("policy", policy)
    prov = Provenance(
        version=version, sources_sha256=sources_digest(), params_hash=params_hash,
        params_file=params_file, params_sha256=params_sha256, rig_file=rig_file,
        rig_sha256=rig_sha256, policy_file=policy_file, policy_sha256=policy_sha256,
    )
    if study is None:
        return prov
    facts = study_facts(study)
    return dataclasses.replace(
        prov, study_file=facts.file, study_sha256=facts.sha256, study_name=facts.name,
        consent_version=facts.consent_version, allocation_seed=facts.allocation_seed,
        preregistration=facts.preregistration,
    )


def _digest(name: str, path: Path | None) -> tuple[str | None, str | None]:
    """(absolute path, SHA-256) of a file given, (None, None) of none; ValueError if unread."""
    if path is None:
        return None, None
    try:
        return str(path.resolve()), file_sha256(path)
    except OSError as exc:
        raise ValueError(f"cannot read the {name} file {path}: {exc.strerror or exc}") from None


class HostsSeen:
    """The hosts each service's heartbeats came from (`rig/status`), as they arrive."""

    def __init__(self) -> None:
        self._seen: dict[str, set[str]] = {}

    def add(self, service: str, host: str) -> None:
        """One heartbeat's service and host (an empty host is not kept)."""
        if host:
            self._seen.setdefault(service, set()).add(host)

    def hosts(self) -> dict[str, tuple[str, ...]]:
        """Each service's hosts, sorted."""
        return {s: tuple(sorted(h)) for s, h in sorted(self._seen.items())}


def metadata(prov: Provenance, session: str) -> dict[str, str]:
    """The recording's `provenance` metadata record: every known field, as text."""
    items = {"session": session, **prov.as_dict()}
    return {k: v if isinstance(v, str) else json.dumps(v) for k, v in items.items()
            if v is not None and v != {}}


def mixed_params(runs: Iterable[tuple[str, str]]) -> str | None:
    """One line naming the sessions of each parameter set, or None when they are one set.

    `runs` are (session, params hash) of every run with a provenance (a session resumed with
    other parameters is in two sets).
    """
    groups: dict[str, list[str]] = {}
    for session, digest in runs:
        if session not in groups.setdefault(digest, []):
            groups[digest].append(session)
    if len(groups) < 2:
        return None

    def named(sessions: list[str]) -> str:
        shown = ", ".join(sorted(sessions)[:SHOWN_SESSIONS])
        more = len(sessions) - SHOWN_SESSIONS
        return shown + (f" and {more} more" if more > 0 else "")

    sets = sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0]))
    return "sessions ran different parameters: " + "; ".join(
        f"params hash {h} ({named(s)})" for h, s in sets)


def metadata_arg(text: str) -> dict[str, str]:
    """`nod record --provenance JSON`: a JSON object of text values (argparse's type)."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not JSON ({exc.msg} at char {exc.pos})") from None
    if not isinstance(value, dict) or not all(isinstance(v, str) for v in value.values()):
        raise argparse.ArgumentTypeError("expected a JSON object of strings")
    return {str(k): v for k, v in value.items()}
