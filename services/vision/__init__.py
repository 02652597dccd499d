"""Vision service: camera capture, hand trackers and buzzer-box calibration."""
