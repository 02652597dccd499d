"""Typed configuration: SPEC defaults live in frozen dataclasses; TOML files override them.

`from_mapping(cls, data)` builds a (possibly nested) dataclass from a TOML table, rejecting
unknown keys and wrong types with a message that names the offending key, so a typo in a lab's
config file fails at start-up instead of silently using a default.

The option set of a session is read here too: a params file whose `[protocol]` table has
`options = [...]` runs that many options (`services.model.schedule.OptionsSchedule`); its
`trials` then name options, and everything else in the file is the paper's `NodConfig` as
`load_params` reads it. Without `options` the file is the paper's, and `--options N`
(`services.core.cli.add_options_arg`; N > 2) picks the default schedule of N options. Two
options are the paper's study, run by its own code (`load_with_options` gives None for them).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from services.model.geometry import COLOURS
from services.model.params import NodConfig
from services.model.schedule import OptionsSchedule, schedule_from_table

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration file or value is invalid; the message says which key and why."""


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file into a dict, with a clear error for a missing or malformed file."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {p}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p} is not valid TOML: {exc}") from None


def _coerce(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    read_table = getattr(tp, "from_config_table", None)
    if read_table is not None:  # a table whose keys are data (an arm's poses by option name)
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {type(value).__name__}")
        try:
            return read_table(value)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: {exc}") from None
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {type(value).__name__}")
        return from_mapping(tp, value, where)
    if origin in (typing.Union, types.UnionType):
        errors = []
        for option in typing.get_args(tp):
            if option is type(None):
                if value is None:
                    return None
                continue
            try:
                return _coerce(option, value, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: invalid value {value!r}")
    if origin is typing.Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(f"{where}: expected one of {typing.get_args(tp)}, got {value!r}")
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected an array, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"{where}: expected {len(args)} items, got {len(value)}")
        return tuple(
            _coerce(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp in (str, bool):
        if not isinstance(value, tp):
            raise ConfigError(f"{where}: expected {tp.__name__}, got {value!r}")
        return value
    return value


def from_mapping(cls: type[T], data: dict[str, Any], where: str = "") -> T:
    """Build dataclass `cls` from a mapping; missing keys keep their defaults."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where or cls.__name__}: unknown key(s) {unknown}; known keys are {sorted(names)}"
        )
    kwargs = {
        key: _coerce(hints[key], value, f"{where}.{key}" if where else key)
        for key, value in data.items()
    }
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where or cls.__name__}: {exc}") from None


def without_option_set(data: dict[str, Any]) -> dict[str, Any]:
    """A params mapping without its option set (`[protocol] options` and the trials naming them).

    A file listing three or more options is the paper's `NodConfig` plus a schedule that only
    the N-option runners read (`load_with_options`); every other reader of the file
    (the eyes, the recorder, the launchers) takes the rest, so one file serves the whole rig.
    """
    protocol = data.get("protocol")
    if not isinstance(protocol, dict) or "options" not in protocol:
        return data
    rest = {k: v for k, v in protocol.items() if k not in ("options", "trials")}
    return {**data, "protocol": rest}


def load_params(path: str | Path | None) -> NodConfig:
    """A rig's parameters: SPEC defaults, overridden by a TOML file when given."""
    if path is None:
        return NodConfig()
    return from_mapping(NodConfig, without_option_set(load_toml(path)))


def split_options(data: dict[str, Any]) -> tuple[dict[str, Any], OptionsSchedule | None]:
    """A params mapping without its option set, and the option set's schedule (None: none)."""
    protocol = data.get("protocol")
    if not isinstance(protocol, dict) or "options" not in protocol:
        return data, None
    try:
        schedule = schedule_from_table(protocol)
    except ValueError as exc:
        raise ConfigError(f"protocol: {exc}") from None
    return without_option_set(data), schedule


def load_with_options(
    path: str | Path | None,
    n_options: int | None = None,
    participant: dict[str, Any] | None = None,
) -> tuple[NodConfig, OptionsSchedule | None]:
    """The parameters and, for more than two options, the N_o-option schedule.

    `n_options` (the `--options` flag; None: the file's, or 2) must agree with a file's list.
    `participant`: traits under the file's `[participant]` (the sim's fitted person).
    """
    data = load_toml(path) if path is not None else {}
    rest, schedule = split_options(data)
    if participant is not None:
        own = rest.get("participant", {})
        if not isinstance(own, dict):
            raise ConfigError(f"{path}: participant: expected a table, got {type(own).__name__}")
        rest = {**rest, "participant": {**participant, **own}}
    cfg = from_mapping(NodConfig, rest)
    if schedule is not None and n_options is not None and n_options != schedule.n_options:
        raise ConfigError(
            f"--options {n_options} but {path} lists {schedule.n_options} options "
            f"{list(schedule.names)}: drop --options or make them agree"
        )
    if schedule is None and n_options is not None and n_options != 2:
        try:
            schedule = OptionsSchedule.default(n_options)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    if schedule is not None and schedule.n_options == 2:
        raise ConfigError(
            "two options are the paper's study: drop [protocol] options (red and blue are "
            "its buzzers) or list three or more"
        )
    return cfg, schedule


def as_dict(obj: Any) -> dict[str, Any]:
    """A dataclass as plain nested dicts, for printing the effective configuration."""
    return dataclasses.asdict(obj)


PARAMS_HASH_DIGITS = 12  # 48 bits: two different parameter sets never meet by chance


def params_hash(cfg: NodConfig) -> str:
    """A short fingerprint of the effective parameters: the first 12 hex digits of a SHA-256.

    Of the values, not of the file: a params file that only repeats SPEC's defaults has the
    hash of no file at all, and comments or key order change nothing. Each service publishes
    it in its heartbeat (`NodeStatus.params_hash`); the conductor compares them with its own.
    """
    text = json.dumps(as_dict(cfg), sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:PARAMS_HASH_DIGITS]


def option_names(schedule: OptionsSchedule | None) -> tuple[str, ...]:
    """The option set a session runs: the paper's red and blue, or the schedule's names."""
    return COLOURS if schedule is None else schedule.names
