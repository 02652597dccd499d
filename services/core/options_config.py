"""The option set of a session: `[protocol] options` in a params file, or `--options N`.

A params file whose `[protocol]` table has `options = [...]` runs that many options
(`services.model.options_schedule`); its `trials` then name options, and everything else in
the file is the paper's `NodConfig` as `load_params` reads it. Without `options` the file is
the paper's, and `--options N` (N > 2) picks the default schedule of N options. Two options
are always the paper's study, with its own code (None here).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from services.core.cli import int_in
from services.core.config import ConfigError, from_mapping, load_toml, without_option_set
from services.model.options_schedule import MAX_OPTIONS, OptionsSchedule, schedule_from_table
from services.model.params import NodConfig


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


def add_options_arg(parser: argparse.ArgumentParser) -> None:
    """`--options N`: run a table of N boxes (default: the params file's, else the paper's 2)."""
    parser.add_argument(
        "--options", type=int_in(2, MAX_OPTIONS), default=None, metavar="N",
        help="options (boxes) on the table: 2 is the paper's study (default), 3 or more run "
        "the N-option rig (docs/multi-option.md); a params file may list them instead",
    )
