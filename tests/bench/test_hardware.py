"""Real devices (skipped unless TPODS_VALVES_URL / TPODS_SCALE_URL are given). Opens no valve."""

import os

import pytest

from bench.ohaus.driver import OhausScout
from bench.valves import ValveController

pytestmark = pytest.mark.hardware


@pytest.mark.skipif(not os.environ.get("TPODS_VALVES_URL"), reason="set TPODS_VALVES_URL")
def test_real_valve_controller_identifies_and_stays_closed():
    with ValveController(os.environ["TPODS_VALVES_URL"]) as v:
        ident = v.identify()
        assert ident.n_channels >= 1
        v.ping()
        assert v.off_confirmed() == (0.0,) * ident.n_channels


@pytest.mark.skipif(not os.environ.get("TPODS_SCALE_URL"), reason="set TPODS_SCALE_URL")
def test_real_balance_reads():
    with OhausScout(os.environ["TPODS_SCALE_URL"],
                    baudrate=int(os.environ.get("TPODS_SCALE_BAUD", "9600"))) as s:
        r = s.read("IP")
        assert r.unit and r.value == r.value
