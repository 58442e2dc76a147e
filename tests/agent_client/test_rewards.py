from __future__ import annotations

import numpy as np
import pytest

from agent_client.rewards import force_reward, force_term, gap_reward, gap_term


def test_gap_term_breakpoints():
    assert gap_term(0.0) == -10.0
    assert gap_term(-3.0) == -10.0  # overlap after a collision
    assert gap_term(30.0) == pytest.approx(0.0)
    assert gap_term(55.0) == pytest.approx(10.0)
    assert gap_term(80.0) == pytest.approx(0.0)
    assert gap_term(300.0) == pytest.approx(-5.0)
    assert gap_term(1000.0) == pytest.approx(-5.0)


def test_gap_term_shape():
    g = np.linspace(0, 300, 3001)
    r = np.array([gap_term(x) for x in g])
    assert g[np.argmax(r)] == pytest.approx(55.0)
    assert np.all(np.diff(r[g <= 55]) > 0) and np.all(np.diff(r[g >= 55]) < 0)
    positive = g[r > 0]
    assert positive.min() == pytest.approx(30.0, abs=0.2) and positive.max() == pytest.approx(80.0, abs=0.2)


def test_force_triangle():
    assert force_term(0.0) == 10.0
    assert force_term(0.15) == pytest.approx(5.0) == force_term(-0.15)
    assert force_term(0.3) == 0.0 and force_term(-1.0) == 0.0


@pytest.mark.parametrize("fn", [gap_reward, force_reward])
def test_normalised_to_unit_interval(fn):
    for g in np.linspace(-5, 400, 200):
        for u in np.linspace(-1, 1, 21):
            assert -1.0 <= fn(g, u) <= 1.0
    assert fn(55.0, 0.0) == pytest.approx(1.0)


def test_gap_reward_ignores_force_and_force_reward_does_not():
    assert gap_reward(50.0, 0.0) == gap_reward(50.0, 1.0)
    assert force_reward(50.0, 0.0) > force_reward(50.0, 0.5)
    assert force_reward(55.0, 1.0) == pytest.approx(0.5)
