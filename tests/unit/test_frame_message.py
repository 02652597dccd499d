"""The monitor's JPEG frame on `vision/frame`: the bytes field, its limits and its key."""

import cv2
import msgpack
import numpy as np
import pytest

from services.core import messages as m
from services.core.keys import Keys
from services.model.geometry import TableLayout
from services.scene.render import SceneRenderer
from services.vision.overlay import monitor_jpeg
from services.vision.trackers import TrackResult


def _raw(**fields):
    return msgpack.packb({"v": m.SCHEMA_VERSION, "seq": 1, "t_ns": 5, **fields}, use_bin_type=True)


def _jpeg():
    frame = SceneRenderer().render((0.5, 0.6))
    result = TrackResult(True, ((0.49, 0.59), (0.51, 0.61)))
    return monitor_jpeg(frame, TableLayout(), result, width=320)


def test_a_monitor_frame_round_trips_and_decodes_as_an_image():
    jpeg, w, h = _jpeg()
    assert (w, h) == (320, 240) and len(jpeg) < 64 * 1024
    msg = m.VisionFrame(seq=3, t_ns=9, jpeg=jpeg, width=w, height=h, hand_seq=41, detected=True)
    back = m.decode(m.VisionFrame, m.encode(msg))
    assert back == msg
    img = cv2.imdecode(np.frombuffer(back.jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (240, 320, 3)


def test_frames_larger_than_the_small_messages_limit_are_accepted_up_to_their_own():
    big = b"\xff\xd8\xff" + bytes(100 * 1024)  # > 64 KiB, < the blob limit
    msg = m.VisionFrame(seq=0, t_ns=0, jpeg=big, width=640, height=480)
    assert m.decode(m.VisionFrame, m.encode(msg)).jpeg == big
    with pytest.raises(m.MessageError, match="exceeds the limit"):
        m.decode(m.HandPose, m.encode(msg))  # other types keep the 64 KiB limit


@pytest.mark.parametrize(
    ("fields", "fragment"),
    [
        ({"jpeg": "not bytes", "width": 1, "height": 1}, "Expected `bytes`, got `str`"),
        ({"jpeg": b"GIF89a", "width": 1, "height": 1}, "must hold a JPEG"),
        ({"width": 1, "height": 1}, "must hold a JPEG"),
        ({"jpeg": b"\xff\xd8\xff", "width": 0, "height": 1}, r"\$.width"),
        (
            {"jpeg": b"\xff\xd8\xff" + bytes(m.MAX_BLOB_BYTES), "width": 1, "height": 1},
            f"length <= {m.MAX_BLOB_BYTES}",
        ),
    ],
)
def test_bad_frames_are_rejected_with_a_reason(fields, fragment):
    with pytest.raises(m.MessageError, match=fragment):
        m.decode(m.VisionFrame, _raw(**fields))


def test_a_whole_payload_beyond_the_frame_limit_is_rejected_before_decoding():
    payload = b"\x00" * (m.VisionFrame.MAX_BYTES + 1)
    with pytest.raises(m.MessageError, match="exceeds the limit"):
        m.decode(m.VisionFrame, payload)


def test_the_frame_key_is_part_of_the_rig_contract():
    keys = Keys("rig1")
    assert keys.topic("vision/frame") == "nod/rig1/vision/frame"
    assert keys.message_type("nod/rig1/vision/frame") is m.VisionFrame


def test_jpeg_quality_steps_down_to_fit_the_limit():
    frame = np.random.default_rng(0).integers(0, 255, (480, 640, 3), np.uint8)  # noise: big JPEG
    jpeg, _, _ = monitor_jpeg(frame, TableLayout(), TrackResult(False), width=640, max_bytes=60_000)
    assert len(jpeg) <= 60_000
