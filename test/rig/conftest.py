"""One compiled rig per test session (compiling the composite takes seconds); tests reset it."""

import pytest

from pcv_sim.rig import Rig, load_rig


@pytest.fixture(scope="session")
def rig_params():
    return load_rig()


@pytest.fixture(scope="session")
def _shared_rig(rig_params):
    return Rig(rig_params)


@pytest.fixture
def rig(_shared_rig):
    _shared_rig.on_input = None
    _shared_rig.reset()
    return _shared_rig
