"""Test-session settings shared by every test module."""

from __future__ import annotations

import cv2
import pytest


@pytest.fixture(autouse=True, scope="session")
def _single_threaded_opencv():
    """OpenCV on one thread for the whole session.

    Tests that fork worker processes (to keep monkeypatched fakes in them) would otherwise inherit
    OpenCV's thread pool from an earlier test and can deadlock in the child; production starts its
    workers with forkserver and is not affected. One thread also keeps timings steady on 2 cores.
    """
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(before)
