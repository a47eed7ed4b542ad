"""The numba chain kernels (wamctl.model.chain_kernels) against pinocchio (WamDynamics) at random states."""

import numpy as np
import pytest

from wamctl.model import params as P
from wamctl.model.chain_kernels import ChainDynamics
from wamctl.model.dynamics import Payload, WamDynamics

TOL = 1e-10


def _odd_links(rng):
    """Link parameters off the datasheet: masses, COMs, inertias and armature all changed."""
    ds = P.LinkParameters.datasheet()
    inertia = ds.inertia_kg_m2 * rng.uniform(0.5, 1.5, ds.inertia_kg_m2.shape)
    inertia[:, 3:] *= 0.3        # keep each inertia positive definite
    return P.LinkParameters(ds.mass_kg * rng.uniform(0.6, 1.6, P.N_JOINTS),
                            ds.com_m + rng.normal(0, 0.02, ds.com_m.shape), inertia,
                            ds.armature_kg_m2 * rng.uniform(0.5, 2.0, P.N_JOINTS))


def _models(seed):
    rng = np.random.default_rng(seed)
    yield WamDynamics()
    yield WamDynamics(Payload(2.5, (0.01, -0.02, 0.06)))
    yield WamDynamics(Payload(1.2, (0.0, 0.03, 0.1)), _odd_links(rng))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_chain_kernels_match_pinocchio(seed):
    rng = np.random.default_rng(100 + seed)
    for dyn in _models(seed):
        chain = ChainDynamics(*dyn.chain_arrays())
        for _ in range(5):
            q = rng.uniform(P.Q_MIN_RAD, P.Q_MAX_RAD)
            qd = rng.normal(0, 2.0, P.N_JOINTS)
            qdd = rng.normal(0, 10.0, P.N_JOINTS)
            tau = rng.normal(0, 20.0, P.N_JOINTS)
            np.testing.assert_allclose(chain.inverse_dynamics(q, qd, qdd), dyn.inverse_dynamics(q, qd, qdd),
                                       rtol=0, atol=TOL)
            np.testing.assert_allclose(chain.nonlinear_effects(q, qd),
                                       dyn.nonlinear_effects_view(q, qd).copy(), rtol=0, atol=TOL)
            np.testing.assert_allclose(chain.gravity(q), dyn.gravity(q), rtol=0, atol=TOL)
            np.testing.assert_allclose(chain.mass_matrix(q), dyn.mass_matrix(q), rtol=0, atol=TOL)
            np.testing.assert_allclose(chain.mass_matrix_inverse(q), dyn.mass_matrix_inverse(q), rtol=0,
                                       atol=TOL * 100)   # entries up to 2.7e3 (the wrist): 1e-8 is 4e-12 relative
            np.testing.assert_allclose(chain.forward_dynamics(q, qd, tau), dyn.forward_dynamics(q, qd, tau),
                                       rtol=1e-10, atol=TOL)


def test_chain_payload_changes_gravity():
    """The payload is in the arrays: gravity on joint 2 at a stretched pose grows by about m g reach."""
    q = np.zeros(P.N_JOINTS)
    q[1] = np.pi / 2
    plain = ChainDynamics(*WamDynamics().chain_arrays())
    loaded = ChainDynamics(*WamDynamics(Payload(2.0)).chain_arrays())
    d = loaded.gravity(q) - plain.gravity(q)
    assert abs(d[1]) > 5.0
    np.testing.assert_allclose(d, WamDynamics(Payload(2.0)).gravity(q) - WamDynamics().gravity(q), atol=TOL)
