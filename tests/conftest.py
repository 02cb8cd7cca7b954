import pytest

from seal.sim.world import LiberoWorld


@pytest.fixture(scope="session")
def world():
    """One real LIBERO-10 task 0 world shared by the fast tests (building one takes ~8 s)."""
    w = LiberoWorld(("libero_10", 0))
    yield w
    w.close()
