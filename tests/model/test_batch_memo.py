"""The batch dynamics keep their last results (wamctl.model.dynamics._BatchMemo): a repeated call gives the numbers
pinocchio gives sample by sample, bit for bit; a caller writing into its result changes nothing kept; another
model (payload, robot) or other inputs never read a kept result; the budget is held."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wamctl.model.dynamics import Payload, WamDynamics, _BatchMemo

RNG = np.random.default_rng(31)


def states(n_joints: int, k: int = 40):
    return (RNG.uniform(-1.0, 1.0, (k, n_joints)), RNG.normal(0.0, 1.0, (k, n_joints)),
            RNG.normal(0.0, 3.0, (k, n_joints)))


def test_repeated_batches_are_pinocchio_bit_for_bit_and_their_own_copies():
    for dyn in (WamDynamics(Payload(0.4, (0.0, 0.02, 0.05))), WamDynamics(robot="wam4")):
        q, qd, qdd = states(dyn.n_joints)
        tau = np.array([pin.rnea(dyn.model, dyn.data, *s).copy() for s in zip(q, qd, qdd)])
        g = np.array([pin.computeGeneralizedGravity(dyn.model, dyn.data, x).copy() for x in q])
        Y = np.array([pin.computeJointTorqueRegressor(dyn.model, dyn.data, *s).copy() for s in zip(q, qd, qdd)])
        for _ in range(2):                      # computed, then kept
            first = dyn.inverse_dynamics_many(q, qd, qdd)
            np.testing.assert_array_equal(first, tau)
            first[:] = np.nan                   # the caller's copy: the kept result is untouched
            np.testing.assert_array_equal(dyn.inverse_dynamics_many(q, qd, qdd), tau)
            gk = dyn.gravity_many(q)
            np.testing.assert_array_equal(gk, g)
            gk += 1.0
            np.testing.assert_array_equal(dyn.gravity_many(q), g)
            np.testing.assert_array_equal(dyn.torque_regressor(q, qd, qdd), Y)


def test_another_model_or_other_inputs_never_read_a_kept_result():
    bare, loaded = WamDynamics(), WamDynamics(Payload(1.5, (0.0, 0.0, 0.1)))
    q, qd, qdd = states(7)
    g_bare = bare.gravity_many(q)
    g_loaded = loaded.gravity_many(q)
    np.testing.assert_array_equal(g_loaded, [loaded.gravity(x) for x in q])
    assert np.abs(g_loaded - g_bare).max() > 0.1          # the payload's own numbers, not the bare arm's
    np.testing.assert_array_equal(bare.inverse_dynamics_many(q, qd, qdd + 1.0),
                                  [bare.inverse_dynamics(*s) for s in zip(q, qd, qdd + 1.0)])
    # the same values in another shape are other inputs (a single state, a prefix)
    np.testing.assert_array_equal(bare.gravity_many(q[0]), bare.gravity(q[0])[None])
    np.testing.assert_array_equal(bare.gravity_many(q[:5]), g_bare[:5])


def test_the_budget_is_held_least_recently_used_first_out():
    memo = _BatchMemo(max_bytes=4 * 800)        # four (100,) float arrays; one larger than a quarter is not kept
    keys = [memo.key(b"x", b"m", np.full(3, float(i))) for i in range(6)]
    for i, k in enumerate(keys[:4]):
        memo.put(k, np.full(100, float(i)))
    assert memo.get(keys[0])[0] == 0.0          # used: now the most recent
    memo.put(keys[4], np.full(100, 4.0))         # evicts keys[1], the least recently used
    assert memo.get(keys[1]) is None and memo.get(keys[0])[0] == 0.0 and memo.get(keys[4])[0] == 4.0
    assert memo._bytes <= memo.max_bytes
    memo.put(keys[5], np.zeros(101))
    assert memo.get(keys[5]) is None
    assert memo.key(b"x", b"m", np.zeros((2, 3))) != memo.key(b"x", b"m", np.zeros((3, 2)))
