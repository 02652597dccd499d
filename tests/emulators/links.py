"""Serial link settings shared by the driver tests.

Healthy paths use a generous reply timeout (a loaded machine must not fail them); tests of
silence use 50 ms so that detection is fast and its bound is visible.
"""

from services.core.serial_link import LinkConfig

LINK = LinkConfig(timeout_s=0.5, backoff_initial_s=0.01, backoff_max_s=0.05)
FAST = LinkConfig(timeout_s=0.05, backoff_initial_s=0.01, backoff_max_s=0.05)
# The drivers' own reply timeout (100 ms, what a rig runs) with fast reconnects: for tests that
# time a fault's detection on a loaded machine, where a pty's replies (pushed by a kernel worker
# at normal priority) can take longer than FAST's 50 ms without any fault.
RIG = LinkConfig(backoff_initial_s=0.01, backoff_max_s=0.05)
