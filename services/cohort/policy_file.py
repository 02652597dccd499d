"""A robot policy's file (TOML) and the policy it makes: `--policy paper|adaptive|FILE.toml`.

    kind = "paper"                 # today's robot (the default everywhere)

    kind = "adaptive"              # the expected-value rule (services.model.policy)
    gaze_levels = ["neutral", "moderate", "extreme"]   # the candidates: every combination
    b_stars = [4.54, 6.0]
    u_rs = [2.24]
    table_people = 150             # simulated people in its table (each explores candidates)
    table_seed = 900000001         # their first seed
    agreement_weight = 0.0         # the value: P(C on O) + this × P(C or CH on O)

`paper` and `adaptive` are the texts in `BUILT_IN` (write one to a file to change it). A
policy's name (a built-in's name, or the file's stem) and the SHA-256 of its bytes are stored
with every session it ran. The adaptive table is built once per (file, configuration) and kept
as JSON in the cache folder
(`NOD_POLICY_CACHE`, default `~/.cache/nod-hri/policy-tables`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from services.cohort.policy_table import Mapper, build_table, table_from_json, table_to_json
from services.model.params import NodConfig
from services.model.policy import AdaptivePolicy, PaperPolicy, Policy, PolicySettings

BUILT_IN = {
    "paper": """\
# The paper's robot: the same b*, u_r and the schedule's gaze level for everyone (today's).
kind = "paper"
""",
    "adaptive": """\
# The adaptive robot: before each consensus trial, the candidate setting with the best predicted
# chance of C on O for this person, from a posterior over kinds of person (strategist,
# contrarian, firm, the rest) against a table of simulated people (docs/adaptive.md).
kind = "adaptive"
# The candidate settings: every combination of these (each inside the params file's [policy]).
gaze_levels = ["neutral", "moderate", "extreme"]
b_stars = [4.54, 6.0]
u_rs = [2.24]
# The table: this many simulated people, each drawing a candidate per consensus trial; seeds
# table_seed, table_seed + 1, ... (far from a cohort's, so its people are ones never seen).
table_people = 1200
table_seed = 900000001
""",
}
TABLE_FORMAT = 2  # the cached tables' layout (`policy_table`): a new one is built when it changes
_KEYS = {"kind", "gaze_levels", "b_stars", "u_rs", "table_people", "table_seed",
         "agreement_weight"}


@dataclass(frozen=True)
class PolicyFile:
    """A policy file as read: its name, its bytes' SHA-256 and its table."""

    name: str
    sha256: str
    data: dict[str, Any]
    text: str = ""  # the file as read (a cohort stores it, so that a resume rebuilds the policy)

    @property
    def kind(self) -> str:
        """Paper or adaptive."""
        return str(self.data["kind"])

    def candidates(self, cfg: NodConfig) -> tuple[PolicySettings, ...]:
        """The adaptive rule's candidate settings, each checked against the envelope."""
        out = tuple(PolicySettings(float(b), g, float(u)) for g, b, u in itertools.product(
            self.data["gaze_levels"], self.data["b_stars"], self.data["u_rs"]))
        outside = [c for c in out if not cfg.policy.contains(c)]
        if outside:
            raise ValueError(f"policy {self.name}: candidate {outside[0]} lies outside the "
                             f"params file's [policy] envelope {cfg.policy}")
        return out


def read_policy_file(arg: str) -> PolicyFile:
    """`paper`, `adaptive` or a TOML file's path, read and checked (ValueError: one line)."""
    if arg in BUILT_IN:
        raw, name = BUILT_IN[arg].encode(), arg
    else:
        try:
            raw, name = Path(arg).read_bytes(), Path(arg).stem
        except OSError as exc:
            raise ValueError(f"--policy {arg}: {exc.strerror or exc} (or name paper, adaptive)"
                             ) from None
    return policy_from_bytes(arg, name, raw)


def policy_from_bytes(arg: str, name: str, raw: bytes) -> PolicyFile:
    """A policy file's bytes, checked (`arg`: where they came from, for the one-line error)."""
    try:
        data = tomllib.loads(raw.decode())
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"--policy {arg}: not TOML: {exc}") from None
    unknown = sorted(set(data) - _KEYS)
    if unknown or data.get("kind") not in ("paper", "adaptive"):
        raise ValueError(f"--policy {arg}: needs kind = \"paper\" or \"adaptive\" and only the "
                         f"keys {sorted(_KEYS)}; got {sorted(data)}")
    if data["kind"] == "adaptive":
        missing = sorted(_KEYS - set(data) - {"agreement_weight"})
        if missing:
            raise ValueError(f"--policy {arg}: an adaptive policy needs {missing}")
    return PolicyFile(name, hashlib.sha256(raw).hexdigest(), data, raw.decode())


def cache_dir() -> Path:
    """Where built tables are kept."""
    env = os.environ.get("NOD_POLICY_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "nod-hri" / "policy-tables"


def make_policy(pf: PolicyFile, cfg: NodConfig, mapper: Mapper | None = None) -> Policy:
    """The policy of a file on this configuration (an adaptive one builds or loads its table)."""
    if pf.kind == "paper":
        return PaperPolicy()
    candidates = pf.candidates(cfg)
    what = [TABLE_FORMAT, pf.sha256, dataclasses.asdict(cfg)]
    key = hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()
    path = cache_dir() / f"{key[:24]}.json"
    weight = float(pf.data.get("agreement_weight", 0.0))
    if path.is_file():
        return AdaptivePolicy(table_from_json(path.read_text()), pf.name, weight)
    table = build_table(cfg, candidates, int(pf.data["table_people"]),
                        int(pf.data["table_seed"]), mapper)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(table_to_json(table))
    tmp.replace(path)
    return AdaptivePolicy(table, pf.name, weight)
