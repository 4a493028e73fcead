"""The hyperelastic densities of nitsche.ops: zero and stress-free at F = I, linear
elasticity for small strains, frame indifference, and P = dW/dF against differences."""
import jax.numpy as jnp
import numpy as np
import pytest

from nitsche.ops import first_piola, lame, neo_hookean, saint_venant_kirchhoff

MU, LAM = lame(1.0, 0.3)
LAWS = [neo_hookean, saint_venant_kirchhoff]


def rotation(d, angle=0.7):
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s], [s, c]])
    return R if d == 2 else np.block([[R, np.zeros((2, 1))], [np.zeros((1, 2)), np.ones((1, 1))]])


@pytest.mark.parametrize("W", LAWS)
@pytest.mark.parametrize("d", [2, 3])
def test_rest_small_strain_frame_indifference_and_stress(W, d):
    I = jnp.eye(d)
    assert float(W(I, MU, LAM)) == pytest.approx(0.0, abs=1e-15)
    assert np.allclose(first_piola(W, I, MU, LAM), 0.0, atol=1e-14)
    rng = np.random.default_rng(d)
    G = rng.standard_normal((d, d))
    eps = 1e-4
    e = 0.5 * eps * (G + G.T)
    linear = MU * np.sum(e * e) + 0.5 * LAM * np.trace(e) ** 2
    assert float(W(I + eps * G, MU, LAM)) == pytest.approx(linear, rel=1e-3)
    F = I + 0.3 * G
    F = F if np.linalg.det(F) > 0 else F @ np.diag([-1.0] + [1.0] * (d - 1))
    assert float(W(jnp.asarray(rotation(d)) @ F, MU, LAM)) == pytest.approx(float(W(F, MU, LAM)), rel=1e-12)
    P = np.asarray(first_piola(W, F, MU, LAM))
    h, H = 1e-6, rng.standard_normal((d, d))
    fd = (float(W(F + h * H, MU, LAM)) - float(W(F - h * H, MU, LAM))) / (2 * h)
    assert np.sum(P * H) == pytest.approx(fd, rel=1e-7)


def test_saint_venant_kirchhoff_softens_in_compression():
    """Uniaxial stretch lambda: P_11 = (mu + lam/2) (lambda^3 - lambda) has its
    minimum at lambda = 1/sqrt(3): the law loses its convexity in strong compression."""
    def P11(stretch):
        F = jnp.diag(jnp.array([stretch, 1.0, 1.0]))
        return float(first_piola(saint_venant_kirchhoff, F, MU, LAM)[0, 0])
    a = 1 / np.sqrt(3)
    assert P11(a) < P11(a - 0.05) and P11(a) < P11(a + 0.05)
    assert P11(1.1) > 0 > P11(0.9)


@pytest.mark.parametrize("d", [2, 3])
def test_current_normal_is_nansons(d):
    """cof(F) N / |cof(F) N| = F^-T N / |F^-T N| for det F > 0, and N itself at F = I."""
    from nitsche.ops import current_normal
    rng = np.random.default_rng(7)
    F = np.eye(d) + 0.3 * rng.standard_normal((d, d))
    N = rng.standard_normal(d)
    N /= np.linalg.norm(N)
    m = np.linalg.solve(F.T, N) * np.sign(np.linalg.det(F))
    assert np.allclose(current_normal(jnp.asarray(F), jnp.asarray(N)), m / np.linalg.norm(m), atol=1e-14)
    assert np.allclose(current_normal(jnp.eye(d), jnp.asarray(N)), N, atol=1e-15)
