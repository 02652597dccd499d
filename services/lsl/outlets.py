"""The rig's two LSL outlets, through `pylsl` (the optional `lsl` extra; its wheel bundles liblsl).

- `nod-<rig>-signals` (type "NOD", double64, irregular rate): ẑ_h, z_r, b_r and the hand
  centre, one sample per hand pose. Irregular, because poses come at the camera's rate with its
  jitter and its drops (camera-rate keys drop when late): each sample carries its own timestamp,
  the pose's, and nothing pretends to a regular rate that LabRecorder's or pyxdf's dejittering
  would then impose on it. Over the paper's two options it has 5 channels (the signed ẑ_h, z_r,
  b_r, then the centre); over N ≥ 3, 3·N + 2 (`samples.signal_names`), and its source_id names
  the options, since a recorder must not take one layout's stream for the other's. The service
  opens it for the paper's options and opens it again for another set when one is first seen.
- `nod-<rig>-markers` (type "Markers", 1 × string, irregular): the protocol's events.

The `source_id`s are fixed per rig, so LabRecorder reconnects to a restarted service's outlets
by itself.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

from services.lsl.samples import signal_names
from services.model.geometry import COLOURS

INSTALL = "pip install 'nod-hri[lsl]'"


def load_pylsl() -> ModuleType:
    """`pylsl`, or ImportError in one line that says how to install it."""
    try:
        return importlib.import_module("pylsl")
    except ImportError as exc:
        raise ImportError(f"the LSL outlet needs pylsl: {INSTALL} ({exc})") from None
    except RuntimeError as exc:  # pylsl found no liblsl for this platform
        raise ImportError(f"pylsl cannot load liblsl: {exc} (set PYLSL_LIB to a liblsl.so)") \
            from None


class Outlets:
    """The signals and markers outlets of one rig, and LSL's clock."""

    def __init__(
        self, rig: str, host: str, offset_s: float, options: tuple[str, ...] = COLOURS
    ) -> None:
        pylsl = load_pylsl()
        self._pylsl = pylsl
        self.rig, self.host = rig, host
        self.local_clock = pylsl.local_clock
        markers = pylsl.StreamInfo(f"nod-{rig}-markers", "Markers", 1, pylsl.IRREGULAR_RATE,
                                   pylsl.cf_string, f"nod-{rig}-markers")
        self._describe(markers, offset_s)
        self.markers: Any = pylsl.StreamOutlet(markers)
        self.signals: Any = _Closed()
        self.options: tuple[str, ...] = ()
        self.open_signals(options, offset_s)

    def open_signals(self, options: tuple[str, ...], offset_s: float) -> None:
        """(Re-)open the signals outlet with the channels of an option set (not once closed)."""
        if isinstance(self.markers, _Closed):
            return
        pylsl = self._pylsl
        names = signal_names(options)
        source = f"nod-{self.rig}-signals"
        if len(options) != 2:
            source += "-" + "-".join(options)
        signals = pylsl.StreamInfo(f"nod-{self.rig}-signals", "NOD", len(names),
                                   pylsl.IRREGULAR_RATE, pylsl.cf_double64, source)
        channels = signals.desc().append_child("channels")
        for name in names:
            ch = channels.append_child("channel")
            ch.append_child_value("label", name)
            ch.append_child_value("unit", "normalised" if name.startswith("hand") else "opinion")
        self._describe(signals, offset_s, options)
        self.options = tuple(options)
        self.signals = pylsl.StreamOutlet(signals)  # the old outlet, if any, closes as it goes

    def _describe(
        self, info: Any, offset_s: float, options: tuple[str, ...] | None = None
    ) -> None:
        meta = info.desc().append_child("nod")
        meta.append_child_value("rig", self.rig)
        meta.append_child_value("host", self.host)
        if options is not None:
            meta.append_child_value("options", ",".join(options))
        # LSL time − rig time (wall s) when the outlet opened: a rig event at t_ns is at
        # t_ns / 1e9 + offset on this host's LSL clock (re-measured every second).
        meta.append_child_value("rig_clock_offset_s", f"{offset_s:.9f}")

    def push_row(self, values: tuple[float, ...], lsl_s: float) -> None:
        """One sample of the signals stream, at `lsl_s` on LSL's clock."""
        self.signals.push_sample(list(values), lsl_s)

    def push_marker(self, text: str, lsl_s: float) -> None:
        """One marker, at `lsl_s` on LSL's clock."""
        self.markers.push_sample([text], lsl_s)

    def close(self) -> None:
        """Close both outlets (idempotent): recorders see the streams end."""
        self.signals = self.markers = _Closed()


class _Closed:
    """An outlet after `close`: pushing is a no-op (a late message while the service stops)."""

    def push_sample(self, *_args: object) -> None:
        """Drop the sample."""
