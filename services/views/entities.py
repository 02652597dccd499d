"""The Rerun entity tree, written once: `services.monitor.bridge` logs to it.

`services.views.blueprint` lays it out, for the monitor and for the recordings:

    opinion/{z_h,z_r,b_r}     two options: time series of the signed ẑ_h, z_r, b_r (one view)
    bars/{z_h,z_r,b_r}        three or more options: a bar chart each, one bar per option
    table/{buzzers,commit_line,hand,arm}   the table: boxes, commit line, hand centre, end effector
    table/{arm_link,gaze}     the arm as a segment from its base, the gaze as arrows from the eyes
    eyes/gaze/{yaw,pitch}     the commanded gaze (rad);  eyes/servos: the servo targets (deg)
    state/{trial,arm,gaze}    protocol phase, arm phase and gaze level as state lanes
    log/{trial,result,arm,safety,services}   text log: events, countdown, outcomes, safety
    camera/frame              the vision service's low-rate JPEG frames
"""

from __future__ import annotations

APPLICATION_ID = "nod_hri"
TIMELINE = "time"  # the message's source timestamp, `t_ns`
TRIAL_TIMELINE = "trial"  # the trial number (0 before the first trial)

ENTITIES: dict[str, str] = {
    "decision/z_h": "opinion/z_h",
    "decision/z_r": "opinion/z_r",
    "decision/b_r": "opinion/b_r",
    "bars/z_h": "bars/z_h",
    "bars/z_r": "bars/z_r",
    "bars/b_r": "bars/b_r",
    "hand": "table/hand",
    "buzzers": "table/buzzers",
    "commit_line": "table/commit_line",
    "arm": "table/arm",
    "arm_link": "table/arm_link",
    "gaze": "table/gaze",
    "gaze_yaw": "eyes/gaze/yaw",
    "gaze_pitch": "eyes/gaze/pitch",
    "servos": "eyes/servos",
    "state_trial": "state/trial",
    "state_arm": "state/arm",
    "state_gaze": "state/gaze",
    "log_trial": "log/trial",
    "log_result": "log/result",
    "log_arm": "log/arm",
    "log_safety": "log/safety",
    "log_services": "log/services",
    "frame": "camera/frame",
}
