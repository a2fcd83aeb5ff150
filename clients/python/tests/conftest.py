"""Fixtures: the real arref-server on a free loopback port, simulated cells (arref_testing.py)."""

import pytest

from arref_testing import Cell, ServerProcess, TrackStream


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    s = ServerProcess(tmp_path_factory.mktemp("server"))
    yield s
    s.stop()


@pytest.fixture(scope="session")
def cell_ros(tmp_path_factory):
    return Cell(tmp_path_factory.mktemp("cell_ros"), "ros", 3)


@pytest.fixture(scope="session")
def cell_unity(tmp_path_factory):
    return Cell(tmp_path_factory.mktemp("cell_unity"), "unity", 3)


@pytest.fixture(scope="session")
def track_stream(tmp_path_factory):
    return TrackStream(tmp_path_factory.mktemp("track"), 7)
