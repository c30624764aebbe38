"""pycolmap's long calls run in a forked child (poses/child.py): results and progress come back, failures become
one-line errors, and Ctrl-C stops the call at once instead of waiting for COLMAP."""
from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from insertnerf_cli.poses.child import ChildFailed, run_in_child


def test_the_result_and_the_progress_messages_come_back():
    seen = []

    def call(send):
        for i in range(3):
            send(i)
        return {"pid": os.getpid(), "value": 42}

    result = run_in_child(call, seen.append)
    assert result["value"] == 42 and result["pid"] != os.getpid() and seen == [0, 1, 2]


def test_a_failure_in_the_child_is_one_line():
    def call(send):
        raise RuntimeError("Failed to read the database\nsecond line")

    with pytest.raises(ChildFailed, match=r"^Failed to read the database$"):
        run_in_child(call)


def test_ctrl_c_kills_the_child_at_once():
    pid_file = []

    def call(send):
        send(os.getpid())
        time.sleep(60)  # a call that does not look at signals, like COLMAP's matcher

    # A process started in the background by a non-interactive shell inherits SIGINT ignored: Ctrl-C's own handler.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    start = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_in_child(call, pid_file.append)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert time.perf_counter() - start < 2.0
    timer.join()
    with pytest.raises(ProcessLookupError):
        os.kill(pid_file[0], 0)  # gone, not left running
