"""The descriptions of `nod export --bids`'s columns and channels: its JSON sidecars' text.

Every column of beh.tsv, events.tsv, participants.tsv and every motion channel is described
here once, with its units and, where it takes a few values, their meaning (BIDS `Levels`).
`services.experiment.bids` fills in what depends on the data (a session's options and gaze
levels, its measured sampling frequency) and writes them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from services.experiment.bids_events import EVENT_TYPES, SOURCES

TASK = "consensus"
TASK_DESCRIPTION = (
    "A person and a robot arm each press one of the buzzers on a table after a countdown; the "
    "robot forms its opinion by nonlinear opinion dynamics from the person's observed hand "
    "motion, with a dynamically controlled bias toward an option O in the consensus trials and "
    "gaze cues from two servo eyes (the paper 'Nonlinear opinion dynamics for human-robot "
    "consensus with robotic eye gaze'). Control (dissensus) trials: no bias, eyes neutral."
)
INSTRUCTIONS = "Press one of the buzzers after 'go'; the robot presses one too."
# Every motion channel type of BIDS: each sidecar counts them all (0 for those not recorded).
CHANNEL_TYPES = ("ACCEL", "ANGACCEL", "GYRO", "JNTANG", "LATENCY", "MAGN", "MISC", "ORNT",
                 "POS", "VEL")
FRAME = "table_image"  # the reference frame of every position channel
FRAME_DESCRIPTION = (
    "The overhead camera's image of the table, normalised to [0, 1]: x to the right, y down "
    "(toward the person; the far edge holds the buzzers). Positions are in this unit, not metres; "
    "the arm's end effector is mapped into the same frame."
)
OUTCOMES = {
    "C": "consensus: both pressed the same buzzer, the person never switched",
    "CH": "consensus after at least one switch of the person",
    "D": "dissensus: different buzzers, no switch",
    "DH": "dissensus after a switch",
}


@dataclass(frozen=True, slots=True)
class Channel:
    """One column of a motion.tsv: a row of its channels.tsv."""

    name: str
    component: str  # x, y or n/a
    type: str  # BIDS motion channel type: POS, MISC, LATENCY
    tracked_point: str
    units: str
    description: str

    @property
    def frame(self) -> str:
        """The channel's reference frame (positions only)."""
        return FRAME if self.type == "POS" else "n/a"


CHANNELS: tuple[Channel, ...] = (
    Channel("latency", "n/a", "LATENCY", "n/a", "s",
            "the sample's time: seconds from the session's start (the clock of events.tsv)"),
    Channel("trial", "n/a", "MISC", "n/a", "n/a", "the trial the sample belongs to"),
    Channel("detected", "n/a", "MISC", "hand", "n/a",
            "1: the tracker found the hand in this frame; 0: it did not (positions n/a)"),
    Channel("hand_x", "x", "POS", "hand", "n/a",
            "the hand centre (mean of the tracker's landmarks), x in the table image"),
    Channel("hand_y", "y", "POS", "hand", "n/a", "the hand centre, y in the table image"),
    Channel("ee_x", "x", "POS", "end_effector", "n/a", "the robot arm's end effector, x"),
    Channel("ee_y", "y", "POS", "end_effector", "n/a", "the robot arm's end effector, y"),
    Channel("z_h", "n/a", "MISC", "n/a", "n/a",
            "the robot's observation of the person's opinion, z_h = a cos(theta) tanh(k/d) "
            "(eq 7): > 0 toward red (option 0), < 0 toward blue"),
    Channel("z_r", "n/a", "MISC", "n/a", "n/a",
            "the robot's opinion z_r (eq 1): > 0 toward option 0 (red)"),
    Channel("b_r", "n/a", "MISC", "n/a", "n/a",
            "the robot's bias b_r (eq 6), dynamically controlled toward O; 0 in control trials"),
    Channel("theta", "n/a", "MISC", "hand", "rad",
            "eq 7's angle theta of the hand's motion for the pose that set z_h"),
    Channel("distance", "n/a", "MISC", "hand", "n/a",
            "eq 7's distance d to the buzzers for the pose that set z_h (table image units)"),
)


def levels(values: Iterable[str], known: dict[str, str] | None = None) -> dict[str, str]:
    """BIDS Levels of the values found: each known meaning, else the value itself."""
    known = known or {}
    return {v: known.get(v, v) for v in sorted(set(values))}


def beh_sidecar(options: list[str], gaze_levels: list[str], note: str) -> dict[str, Any]:
    """beh.json: every column of beh.tsv with its units and levels."""
    opt = levels(options, {options[0]: "option 0 (z > 0)"} if options else None)
    return {
        "TaskName": TASK,
        "TaskDescription": TASK_DESCRIPTION,
        "Instructions": INSTRUCTIONS,
        "Notes": note,
        "trial": {"Description": "the trial's number in the session's protocol"},
        "mode": {"Description": "the trial's kind", "Levels": {
            "dissensus": "a control trial: bias controller off (b_r = 0), eyes neutral",
            "consensus": "an experiment trial: the bias and the gaze favour the option O"}},
        "option": {"Description": "O, the option the robot's bias and gaze favour (n/a in "
                   "control trials)", "Levels": opt},
        "gaze_level": {"Description": "the strength of the trial's gaze cue",
                       "Levels": levels(gaze_levels)},
        "gaze_yaw": {"Description": "the eyes' yaw for the trial's cue", "Units": "rad"},
        "gaze_pitch": {"Description": "the eyes' pitch for the trial's cue", "Units": "rad"},
        "go_onset": {"Description": "the start signal ('go'), from the session's start (n/a: "
                     "the trial never reached it)", "Units": "s"},
        "end_onset": {"Description": "the trial's end, from the session's start", "Units": "s"},
        "human": {"Description": "the buzzer the person pressed in time (n/a: none, a timeout)",
                  "Levels": opt},
        "robot": {"Description": "the buzzer the robot pressed (n/a: none)", "Levels": opt},
        "outcome": {"Description": "the trial's class (n/a: a timeout or an interrupted trial)",
                    "Levels": OUTCOMES},
        "switches": {"Description": "the person's debounced changes of direction"},
        "violations": {"Description": "rule violations: a second switch, or one after the "
                       "commit line"},
        "clicks": {"Description": "counter clicks the operator entered (n/a: not entered)"},
        "score": {"Description": "the trial's points (paper Sec 3.2)"},
        "end_reason": {"Description": "what ended the trial, in words"},
        "interrupted": {"Description": "whether a safe stop or an e-stop broke the trial's last "
                        "start, so it was never scored",
                        "Levels": {"0": "completed", "1": "interrupted, never scored"}},
        "attempts": {"Description": "starts of this trial, the interrupted ones included"},
    }


def policy_columns(policy: bool, estimated: Iterable[str]) -> dict[str, Any]:
    """beh.json's entries for the columns of a robot policy's settings and of the estimates."""
    out: dict[str, Any] = {}
    if policy:
        out["policy_b_star"] = {"Description": "eq 6's bias threshold b* the robot policy chose "
                                "for the trial (its gaze level is gaze_level)"}
        out["policy_u_r"] = {"Description": "eq 1's robot attention u_r the robot policy chose "
                             "for the trial"}
    names = list(estimated)
    if names:
        out["estimate_trials_seen"] = {
            "Description": "of the trials up to this one, how many the live estimator (nod "
            "estimate) heard; the estimate columns are its estimate after this trial"}
    for n in names:
        out[f"estimate_{n}"] = {"Description": f"the participant's {n} estimated from their "
                                "trials so far (nod fit's estimator for partial sessions; a 0/1 "
                                "parameter: its most likely value)"}
        out[f"estimate_{n}_low"] = {"Description": f"the lower end of {n}'s 90 % interval (a "
                                    "0/1 parameter: the least value of its 90 % set)"}
        out[f"estimate_{n}_high"] = {"Description": f"the upper end of {n}'s 90 % interval (a "
                                     "0/1 parameter: the largest value of its 90 % set)"}
    return out


def events_sidecar(note: str, version: str) -> dict[str, Any]:
    """events.json: the columns of events.tsv."""
    return {
        "TaskName": TASK,
        "TaskDescription": TASK_DESCRIPTION,
        "Instructions": INSTRUCTIONS,
        "StimulusPresentation": {
            "SoftwareName": "nod-hri (nod experiment's protocol; nod speaker, nod eyes)",
            "SoftwareVersion": version,
        },
        "Notes": note,
        "onset": {"Description": "when it happened, from the session's start", "Units": "s"},
        "duration": {"Description": "how long it lasted (0: an instant)", "Units": "s"},
        "trial_type": {"Description": "what happened", "Levels": dict(EVENT_TYPES)},
        "trial": {"Description": "the trial under way (n/a: before the first)"},
        "attempt": {"Description": "which start of that trial"},
        "value": {"Description": "the word, option, level or reason (see trial_type)"},
        "planned_onset": {"Description": "when the protocol asked for it (cues), from the "
                          "session's start; the speaker played it at onset", "Units": "s"},
        "source": {"Description": "where onset comes from", "Levels": dict(SOURCES)},
    }


def participants_sidecar() -> dict[str, Any]:
    """participants.json: the columns of participants.tsv (no names: a pseudonymous id)."""
    return {
        "participant_id": {"Description": "the study's pseudonymous id, as stored (no names)"},
        "sessions": {"Description": "the participant's sessions in this dataset"},
        "status": {"Description": "how their last session ended", "Levels": {
            "complete": "every trial done", "aborted": "stopped before the end",
            "running": "left running (a crash); its stored trials are exported"}},
        "simulated": {"Description": "whether the person was simulated, not a human",
                      "Levels": {"true": "a simulated participant (nod sim, or the offline "
                                 "closed loop of nod cohort)", "false": "a person on a rig"}},
        "rig": {"Description": "the rig their sessions ran on ('offline': no rig, the "
                "offline closed loop)"},
        "order": {"Description": "the study's condition: the option O of each consensus trial "
                  "of their first session, in trial order (space separated)"},
        "consent_version": {"Description": "the version of the consent form they signed (n/a: "
                            "not recorded)"},
    }


def sessions_sidecar() -> dict[str, Any]:
    """sessions.json: the columns of a participant's sessions.tsv."""
    return {
        "session_id": {"Description": "ses-<n>: the participant's n-th session, oldest first"},
        "status": participants_sidecar()["status"],
        "simulated": participants_sidecar()["simulated"],
        "order": {"Description": "the option O of each consensus trial, in trial order"},
    }


def channels_sidecar() -> dict[str, Any]:
    """channels.json: the reference frame of the position channels."""
    return {
        "reference_frame": {
            "Description": "the frame the positions are in",
            "Levels": {FRAME: {"Description": FRAME_DESCRIPTION, "SpatialAxes": "RB_",
                               "RotationRule": "n/a", "RotationOrder": "n/a"}},
        },
    }
