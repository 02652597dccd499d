"""Check the paper's Sec 4.4.1 "square claim" against a computed bias sweep (SPEC §3, §8).

The paper states the consensus region two ways:

* ``outside`` (Fig 3a text): consensus when (b_r, b_h) lies outside the square of half-side u
  centred at the origin, max(|b_r|, |b_h|) > u, and sgn b_r = sgn b_h;
* ``both`` (Fig 3b text): consensus when both |b_r| > u and |b_h| > u, with the same sign.

Each reading is compared point by point with the computed consensus map; the report gives the
agreement fraction, the two kinds of disagreement, and where they sit.
"""

from __future__ import annotations

from typing import Any, Literal, TypeAlias

import numpy as np

from services.analysis.sweep import SweepResult

Reading: TypeAlias = Literal["outside", "both"]
READINGS: tuple[Reading, Reading] = ("outside", "both")


def square_claim(b_r: np.ndarray, b_h: np.ndarray, u: float, reading: Reading) -> np.ndarray:
    """The claim's consensus prediction on the grid, indexed [i, j] for (b_h[i], b_r[j])."""
    BR, BH = np.meshgrid(np.asarray(b_r, float), np.asarray(b_h, float))
    same_sign = (np.sign(BR) == np.sign(BH)) & (BR != 0)
    if reading == "outside":
        return same_sign & (np.maximum(np.abs(BR), np.abs(BH)) > u)
    if reading == "both":
        return same_sign & (np.abs(BR) > u) & (np.abs(BH) > u)
    raise ValueError(f"unknown reading {reading!r}; choose one of {READINGS}")


def _region(mask: np.ndarray, BR: np.ndarray, BH: np.ndarray, u: float) -> dict[str, Any] | None:
    """Where a set of grid points sits: count per quadrant and the ranges of |b_r|, |b_h|."""
    if not mask.any():
        return None
    ar, ah = np.abs(BR[mask]), np.abs(BH[mask])
    quadrants = {
        "b_r>0,b_h>0": int(np.sum(mask & (BR > 0) & (BH > 0))),
        "b_r<0,b_h<0": int(np.sum(mask & (BR < 0) & (BH < 0))),
        "opposite signs or zero": int(np.sum(mask & ~((BR * BH) > 0))),
    }
    return {
        "count": int(mask.sum()),
        "quadrants": quadrants,
        "abs_b_r_range": [float(ar.min()), float(ar.max())],
        "abs_b_h_range": [float(ah.min()), float(ah.max())],
        "min_abs_b_r_over_u": float(ar.min() / u),
        "min_abs_b_h_over_u": float(ah.min() / u),
    }


def _edge_thresholds(result: SweepResult) -> dict[str, float | None]:
    """Computed consensus thresholds in the positive quadrant, read off the grid.

    `b_h_at_max_b_r`: the smallest b_h > 0 giving consensus on the column b_r = max(b_r);
    `b_r_at_max_b_h`: likewise for b_r on the row b_h = max(b_h); `diagonal`: the smallest
    b > 0 on the diagonal b_r = b_h with consensus (only for a square grid with b_r = b_h).
    """
    c = result.consensus

    def first(values: np.ndarray, flags: np.ndarray) -> float | None:
        sel = (values > 0) & flags
        return float(values[sel].min()) if sel.any() else None

    out = {
        "b_h_at_max_b_r": first(result.b_h, c[:, int(np.argmax(result.b_r))]),
        "b_r_at_max_b_h": first(result.b_r, c[int(np.argmax(result.b_h)), :]),
        "diagonal": None,
    }
    if result.b_r.shape == result.b_h.shape and np.array_equal(result.b_r, result.b_h):
        out["diagonal"] = first(result.b_r, np.diag(c))
    return out


def check_square_claim(result: SweepResult, u: float) -> dict[str, Any]:
    """Compare both readings of the claim with `result`'s consensus map (see module doc)."""
    computed = result.consensus
    BR, BH = np.meshgrid(result.b_r, result.b_h)
    n = int(computed.size)
    report: dict[str, Any] = {
        "u": float(u),
        "grid": [int(result.b_h.size), int(result.b_r.size)],
        "b_range": [float(result.b_r.min()), float(result.b_r.max())],
        "points": n,
        "converged_fraction": float(result.converged.mean()),
        "computed_consensus_fraction": float(computed.mean()),
        "computed_thresholds": _edge_thresholds(result),
        "readings": {},
    }
    for reading in READINGS:
        claim = square_claim(result.b_r, result.b_h, u, reading)
        agree = claim == computed
        false_consensus = claim & ~computed  # claim says consensus, dynamics says dissensus
        missed_consensus = ~claim & computed  # dynamics says consensus, claim does not
        regions = {
            "claim_consensus_computed_dissensus": _region(false_consensus, BR, BH, u),
            "claim_dissensus_computed_consensus": _region(missed_consensus, BR, BH, u),
        }
        report["readings"][reading] = {
            "agree": int(agree.sum()),
            "agree_fraction": float(agree.mean()),
            "disagree": int((~agree).sum()),
            "claim_is_sufficient": bool(not false_consensus.any()),
            "claim_is_necessary": bool(not missed_consensus.any()),
            **regions,
        }
    return report


def format_report(report: dict[str, Any]) -> str:
    """A short plain-text summary of `check_square_claim`."""
    lo, hi = report["b_range"]
    lines = [
        f"u = {report['u']:.6g}, grid {report['grid'][0]}×{report['grid'][1]} over "
        f"[{lo:g}, {hi:g}]², computed consensus {report['computed_consensus_fraction']:.2%}, "
        f"converged {report['converged_fraction']:.2%}",
        f"computed thresholds (positive quadrant): {report['computed_thresholds']}",
    ]
    for name, r in report["readings"].items():
        lines.append(
            f"reading '{name}': agree {r['agree']}/{report['points']} ({r['agree_fraction']:.2%});"
            f" sufficient={r['claim_is_sufficient']}, necessary={r['claim_is_necessary']}"
        )
        for key in ("claim_consensus_computed_dissensus", "claim_dissensus_computed_consensus"):
            reg = r[key]
            if reg:
                lines.append(
                    f"  {key}: {reg['count']} points, |b_r| in {reg['abs_b_r_range']}, "
                    f"|b_h| in {reg['abs_b_h_range']}, {reg['quadrants']}"
                )
    return "\n".join(lines)
