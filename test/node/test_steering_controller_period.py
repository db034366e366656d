"""The example controller node's period check: jitter of real-time stamps is not a wrong period."""
import numpy as np

from pcv_sim.node.steering_controller import PeriodCheck

EPOCH_NS = 1_795_628_971_231_000_000          # real time: stamps are wall-clock epoch ns


def _stamps(period_ns, n, *, skip=()):
    """Sample stamps as the controller gets them (integer ns x 1e-9), `skip` sample indices left out."""
    k = np.array([i for i in range(n) if i not in skip])
    return [int(ns) * 1e-9 for ns in EPOCH_NS + k * period_ns]


def _warnings(check, stamps):
    return [w for w in (check(t) for t in stamps) if w is not None]


def test_real_time_stamps_at_the_period_do_not_warn():
    stamps = _stamps(1_000_000, 400, skip={7, 8, 30})          # two samples the rig skipped, too
    gaps = np.diff(stamps)
    assert np.any(np.abs(gaps - 1e-3) > 1e-7)                  # float64 epoch seconds: ~0.24 us steps
    assert _warnings(PeriodCheck(1e-3), stamps) == []


def test_a_wrong_period_warns_once_with_the_rig_s():
    warnings = _warnings(PeriodCheck(1e-3), _stamps(2_000_000, 400))
    assert len(warnings) == 1
    assert "samples 2 ms apart" in warnings[0] and "set -p period:=0.002 " in warnings[0], warnings


def test_a_restart_is_not_an_interval():
    check = PeriodCheck(1e-3)
    first = _stamps(1_000_000, 30)
    assert _warnings(check, first) == []
    check.restart()                                            # the rig started again from model time 0
    assert _warnings(check, [k * 1e-3 for k in range(40)]) == []
