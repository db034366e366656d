"""bags/ regenerates from the code (the child process was started by conftest.regeneration).

Bit for bit on the machine that made them; elsewhere the stiff solver's LAPACK (OpenBLAS picks
its kernels by processor) can differ in the last bits, which flips the rounding of an output
that lies on a quantisation boundary (bags/README.md): such a sample then differs by exactly one
quantum. So: the same files, topics, times, inputs and metadata, and outputs within one quantum
in a handful of samples. Anything more is a changed model, config or package.
"""

from __future__ import annotations

import numpy as np

from pcv_sim.io.bag import read_bag
from pcv_sim.replay.reference_bags import QUANTUM

from .conftest import BAGS, REFERENCE_BAGS


def test_reference_bags_regenerate_from_the_code(regeneration):
    out, _ = regeneration.proc.communicate(timeout=240)
    assert regeneration.proc.returncode == 0, out
    hint = ("If the model, config/valve.yaml or a pinned package changed on purpose, run "
            "`pcv-sim reference-bags` and commit bags/ (bags/README.md)")
    for name in REFERENCE_BAGS:
        committed = sorted(p.name for p in (BAGS / name).iterdir())
        fresh = sorted(p.name for p in (regeneration.out / name).iterdir())
        assert committed == fresh == ["metadata.yaml", f"{name}_0.mcap"]
        # metadata.yaml holds no model output (counts, times, QoS, distribution): the same bytes.
        meta = "metadata.yaml"
        assert (BAGS / name / meta).read_bytes() == (regeneration.out / name / meta).read_bytes(), (name, hint)
        a, b = read_bag(BAGS / name), read_bag(regeneration.out / name)
        assert a.topic_types == b.topic_types
        for topic in a.topics:
            sa, sb = a[topic], b[topic]
            assert np.array_equal(sa.t_ns, sb.t_ns), (name, topic, hint)
            role = topic.strip("/")
            if role in QUANTUM:
                diff = np.abs(sa.value - sb.value)
                assert np.all(diff <= QUANTUM[role] * (1 + 1e-9)), (name, topic, float(diff.max()), hint)
                assert np.count_nonzero(diff) <= 0.01 * len(diff), (name, topic, np.count_nonzero(diff), hint)
            else:
                assert np.array_equal(sa.value, sb.value), (name, topic, hint)
