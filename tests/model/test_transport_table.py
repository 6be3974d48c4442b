"""The two-layer transport table: accuracy against direct adding-doubling, exact derivatives of the
interpolant, jit/vmap/grad, dtypes, clamping outside the box, building, saving and caching."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit  # noqa: F401 - float64
from skinfit.model import _transport_table as tt
from skinfit.model import Layer, monte_carlo_reflectance, stack_reflectance_transport

#: Largest relative error against adding-doubling at skin-like points: measured 6.7e-5 over 1,000
#: points by benchmarks/build_transport_table.py (benchmarks/results/transport_table.json), 2.2e-5
#: at the 50 here; the 65 x 49 x 65 grid's was 4.4e-3.
SKIN_TOLERANCE = 1e-4


@pytest.fixture(scope="module")
def table():
    return tt.transport_table()


def skin_stacks(n, seed):
    """(sigma_a1, sigma_s1', d, sigma_a2, sigma_s2') rows: sigma_s' 2-40 mm^-1, d 0.02-0.3 mm,
    sigma_a 0.01-200 mm^-1, log-uniform."""
    rng = np.random.default_rng(seed)
    draw = lambda lo, hi: np.exp(rng.uniform(np.log(lo), np.log(hi), n))  # noqa: E731
    return np.stack([draw(0.01, 200.0), draw(2.0, 40.0), draw(0.02, 0.3), draw(0.01, 200.0), draw(2.0, 40.0)], -1)


@functools.partial(jax.jit, static_argnames=("g", "ior", "streams"))
def _direct(stacks, g, ior, streams):
    def one(s):
        return stack_reflectance_transport(jnp.stack([s[0], s[3]]), jnp.stack([s[1], s[4]]), jnp.stack([s[2], 1.0]), jnp.full(2, g),
                                           ior=ior, ior_above=1.0, semi_infinite=True, streams=streams)

    return jax.vmap(one)(stacks)


def direct(stacks, g=0.8, ior=1.4, streams=16):
    """Adding-doubling of the two-layer stacks (n, 5), n <= 64: padded to 64 rows (one compilation)."""
    padded = np.concatenate([stacks, np.repeat(stacks[-1:], 64 - len(stacks), axis=0)])
    return np.asarray(_direct(jnp.asarray(padded), g, ior, streams))[: len(stacks)]


def test_shipped_table_matches_adding_doubling_at_skin_like_points(table):
    assert (table.anisotropy, table.ior, table.streams) == (0.8, 1.4, 16)
    stacks = skin_stacks(50, seed=2024)
    got = np.asarray(table.reflectance(*stacks.T))
    error = np.abs(got / direct(stacks) - 1.0)
    assert error.max() < SKIN_TOLERANCE, (error.max(), stacks[np.argmax(error)])


#: Two-layer stacks at the table's anisotropy (0.8) and index (1.4): a 0.25 mm epidermis over a
#: semi-infinite dermis, (sigma_a, sigma_s') of each in mm^-1 (the g = 0.8 stacks of test_transport.py).
MONTE_CARLO_STACKS = [(0.5, 6.0, 0.05, 3.0), (50.0, 10.0, 0.5, 2.0), (1.0, 2.0, 0.02, 10.0)]


@pytest.mark.slow
@pytest.mark.parametrize("stack", MONTE_CARLO_STACKS, ids=[f"epi{s[0]}-{s[1]}_derm{s[2]}-{s[3]}" for s in MONTE_CARLO_STACKS])
def test_table_matches_monte_carlo(table, stack):
    sa1, ss1, sa2, ss2 = stack
    layers = [Layer(absorption=sa1, reduced_scattering=ss1, thickness=0.25, ior=1.4, anisotropy=0.8),
              Layer(absorption=sa2, reduced_scattering=ss2, thickness=float("inf"), ior=1.4, anisotropy=0.8)]
    got = float(table.reflectance(sa1, ss1, 0.25, sa2, ss2))
    # 200,000 photons: the Monte Carlo's standard error is 0.2-1.3 % of R here (measured 0.2, 1.3, 0.25 %);
    # the table agreed within 0.6, 1.1 and 1.3 of it (2026-12-02)
    mc = monte_carlo_reflectance(layers, photons=200_000, seed=11)
    assert abs(got - mc.reflectance) <= 5e-3 * mc.reflectance + 3 * mc.reflectance_error, (got, mc.reflectance, mc.reflectance_error)


def test_saturated_epidermis_is_its_semi_infinite_limit(table):
    # optical depth 1e4: where the direct two-layer solver overflows, the table holds the limit
    limit = direct(np.array([[100.0, 1.0, 1.0, 100.0, 1.0]]))[0]  # dermis = epidermis
    assert float(table.reflectance(100.0, 1.0, 99.0, 1e-4, 1.0)) == pytest.approx(limit, rel=1e-4)


def test_gradient_matches_finite_differences(table):
    stacks = skin_stacks(4, seed=5)
    gradient = jax.jit(jax.vmap(jax.grad(lambda s: table.reflectance(*s))))(jnp.asarray(stacks))
    for row, grad in zip(stacks, np.asarray(gradient)):
        for i in range(5):
            h = 1e-5 * row[i]
            up, down = row.copy(), row.copy()
            up[i] += h
            down[i] -= h
            fd = (float(table.reflectance(*up)) - float(table.reflectance(*down))) / (2 * h)
            assert grad[i] == pytest.approx(fd, rel=1e-5, abs=1e-9 * abs(float(table.reflectance(*row))) / row[i])


def test_explicit_derivative_rule_matches_differentiating_the_contractions(table):
    """The spline's JVP rule (value and gradient from one stencil) against automatic differentiation
    of the plain contractions: first and second derivatives, in the coordinates and the coefficients."""

    def contracted(coefficients, x):
        block, u = tt._stencil(coefficients, tuple(x[:, i] for i in range(3)), table.lower, table.step)
        block = jnp.einsum("mabc,mc->mab", block, tt._bspline_weights(u[2]))
        block = jnp.einsum("mab,mb->ma", block, tt._bspline_weights(u[1]))
        return jnp.einsum("ma,ma->m", block, tt._bspline_weights(u[0]))

    def ruled(coefficients, x):
        return tt._spline(coefficients, x[:, 0], x[:, 1], x[:, 2], table.lower, table.step)

    rng = np.random.default_rng(17)
    x = jnp.asarray(np.stack([rng.uniform(lo + 0.1, hi - 0.1, 5) for lo, hi in zip(table.lower, table.upper)], axis=1))
    c = table.coefficients
    np.testing.assert_allclose(ruled(c, x), contracted(c, x), rtol=1e-13)
    for order in (jax.jacfwd, jax.jacrev):
        np.testing.assert_allclose(order(ruled, 1)(c, x), order(contracted, 1)(c, x), rtol=1e-11, atol=1e-12)
    hessian = lambda f: jax.vmap(jax.hessian(lambda xi: f(c, xi[None])[0]))(x)  # noqa: E731
    np.testing.assert_allclose(hessian(ruled), hessian(contracted), rtol=1e-10, atol=1e-10)
    direction = jnp.asarray(rng.standard_normal(c.shape))  # the spline is linear in its coefficients
    along = lambda f: jax.jvp(lambda k: f(k, x), (c,), (direction,))[1]  # noqa: E731
    np.testing.assert_allclose(along(ruled), along(contracted), rtol=1e-12)


def test_jit_vmap_grad_and_broadcasting(table):
    stacks = skin_stacks(6, seed=9)
    args = [jnp.asarray(c) for c in stacks.T]
    eager = table.reflectance(*args)
    assert eager.shape == (6,)
    np.testing.assert_allclose(jax.jit(lambda t, *a: t.reflectance(*a))(table, *args), eager, rtol=1e-13)
    np.testing.assert_allclose(eqx.filter_jit(lambda t, a: t.reflectance(*a))(table, args), eager, rtol=1e-13)
    np.testing.assert_allclose(jax.vmap(table.reflectance)(*args), eager, rtol=1e-13)
    # a spectrum: 31 wavelengths of absorption and scattering, one thickness
    spectrum = table.reflectance(jnp.linspace(0.5, 20.0, 31), jnp.linspace(8.0, 3.0, 31), 0.1, jnp.linspace(0.05, 2.0, 31), 2.5)
    assert spectrum.shape == (31,) and np.all(np.isfinite(spectrum))
    assert table.reflectance(jnp.ones((2, 1)), 5.0, 0.1, jnp.full(3, 0.1), 3.0).shape == (2, 3)
    assert table.reflectance(1.0, 5.0, 0.1, 0.1, 3.0).shape == ()
    # forward and reverse mode agree, under jit
    forward = jax.jit(jax.jacfwd(lambda s: table.reflectance(*s)))(jnp.asarray(stacks[0]))
    reverse = jax.jit(jax.grad(lambda s: table.reflectance(*s)))(jnp.asarray(stacks[0]))
    np.testing.assert_allclose(forward, reverse, rtol=1e-12)
    # more absorption in either layer darkens
    assert reverse[0] < 0 and reverse[3] < 0
    # the coefficients are the table's only array leaf: derivatives reach them too
    leaves = jax.tree_util.tree_leaves(table)
    assert len(leaves) == 1 and leaves[0] is table.coefficients
    d_table = jax.grad(lambda t: t.reflectance(*stacks[0]))(table)
    assert np.isfinite(np.asarray(d_table.coefficients)).all() and np.count_nonzero(np.asarray(d_table.coefficients)) == 64


def test_float32_in_float32_out(table):
    stacks = skin_stacks(20, seed=13)
    r64 = table.reflectance(*stacks.T)
    r32 = table.reflectance(*stacks.T.astype(np.float32))
    assert r64.dtype == jnp.float64 and r32.dtype == jnp.float32
    np.testing.assert_allclose(r32, r64, rtol=2e-5)
    grad32 = jax.grad(lambda a: jnp.sum(table.reflectance(a, 10.0, 0.1, 0.3, 3.0)))(jnp.float32(2.0))
    assert grad32.dtype == jnp.float32 and np.isfinite(grad32)


@pytest.mark.parametrize(
    "outside, inside",
    [
        ((1e-12, 5.0, 0.1, 0.2, 3.0), (5e-5, 5.0, 0.1, 0.2, 3.0)),  # sigma_a1 / sigma_s1' below 1e-5
        ((1e6, 5.0, 0.1, 0.2, 3.0), (500.0, 5.0, 0.1, 0.2, 3.0)),  # above 1e2
        ((1.0, 5.0, 1e-9, 0.2, 3.0), (1.0, 5.0, 2e-3, 0.2, 3.0)),  # sigma_s1' d below 1e-2
        ((1e-3, 5.0, 1e6, 0.2, 3.0), (1e-3, 5.0, 20.0, 0.2, 3.0)),  # above 1e2
        ((1.0, 5.0, 0.1, 1e-20, 3.0), (1.0, 5.0, 0.1, 3e-5, 3.0)),  # dermis below
        ((1.0, 5.0, 0.1, 1e8, 3.0), (1.0, 5.0, 0.1, 300.0, 3.0)),  # dermis above
    ],
)
def test_clamped_outside_the_box(table, outside, inside):
    value = table.reflectance(*outside)
    assert np.isfinite(value) and float(value) == pytest.approx(float(table.reflectance(*inside)), rel=1e-12)
    grad = jax.grad(lambda s: table.reflectance(*s))(jnp.asarray(outside))
    assert np.all(np.isfinite(grad))


def test_zero_absorption_and_zero_thickness_are_finite(table):
    for stack in [(0.0, 5.0, 0.1, 0.0, 3.0), (0.0, 5.0, 0.0, 0.0, 3.0), (2.0, 5.0, 0.0, 0.0, 3.0)]:
        value, grad = jax.value_and_grad(lambda s: table.reflectance(*s))(jnp.asarray(stack))
        assert np.isfinite(value) and np.all(np.isfinite(grad)), (stack, value, grad)
    # no absorption anywhere: almost everything that enters comes back out
    assert 0.95 < float(table.reflectance(0.0, 5.0, 0.1, 0.0, 3.0)) < table.max_reflectance


def test_tiny_table_interpolates_its_nodes_and_round_trips(tmp_path):
    nodes = (4, 5, 4)
    small = tt.build_transport_table(0.8, 1.4, streams=4, nodes=nodes, progress=False)
    assert small.nodes == nodes and small.coefficients.shape == (6, 7, 6)
    axes = tt.grid_axes(nodes)
    x = np.stack([a.ravel() for a in np.meshgrid(*axes, indexing="ij")], -1)[::7]
    r1, sd, r3 = np.exp(x).T
    # beyond the saturation thickness a node holds the reflectance there (where the direct solver drifts)
    sd_node = np.minimum(sd, np.exp(tt.saturation_thickness(x[:, 0], 0.8)))
    assert np.any(sd_node < sd) and np.any(sd_node == sd)
    exact = direct(np.stack([r1, np.ones_like(r1), sd_node, r3, np.ones_like(r1)], -1), streams=4)
    np.testing.assert_allclose(small.reflectance(r1, 1.0, sd, r3, 1.0), exact, rtol=2e-6)  # float32 coefficients
    path = tt.save_table(small, tmp_path / "tiny.npz")
    loaded = tt.load_table(path)
    assert (loaded.lower, loaded.step, loaded.anisotropy, loaded.ior, loaded.streams, loaded.nodes) == (
        small.lower, small.step, small.anisotropy, small.ior, small.streams, small.nodes)
    np.testing.assert_array_equal(loaded.coefficients, small.coefficients)
    point = (0.3, 4.0, 0.05, 0.02, 2.0)
    assert float(loaded.reflectance(*point)) == float(small.reflectance(*point))


def test_other_anisotropy_is_built_once_and_cached_on_disk(tmp_path, monkeypatch):
    monkeypatch.setenv("SKINFIT_CACHE_DIR", str(tmp_path))
    nodes = (4, 4, 4)
    built = tt.transport_table(0.5, 1.4, streams=4, nodes=nodes, progress=False)
    files = list((tmp_path / "transport").glob("*.npz"))
    assert len(files) == 1 and built.anisotropy == 0.5
    assert tt.transport_table(0.5, 1.4, streams=4, nodes=nodes, progress=False) is built  # in memory

    def no_build(*args, **kwargs):
        raise AssertionError("should load the cached table, not build")

    tt.transport_table.cache_clear()
    monkeypatch.setattr(tt, "build_transport_table", no_build)
    loaded = tt.transport_table(0.5, 1.4, streams=4, nodes=nodes, progress=False)
    tt.transport_table.cache_clear()  # leave no table built under this test's cache directory behind
    assert loaded is not built
    np.testing.assert_array_equal(loaded.coefficients, built.coefficients)
    # another g is another table
    assert float(loaded.reflectance(1.0, 5.0, 0.1, 0.1, 3.0)) != pytest.approx(float(tt.transport_table().reflectance(1.0, 5.0, 0.1, 0.1, 3.0)))
