"""Manoeuvre filter of the dynamic state (design §7.2 departure): float path = array path."""


def test_manoeuvre_filter_float_path_equals_array_path():
    """The online (ax, ay) float path must give exactly the offline array path's numbers,
    including the hold on non-finite samples, so online and offline states agree."""
    import numpy as np

    from terrainml.estimation.dynamic_state import ManoeuvreFilter

    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.005, 0.015, 500))
    a = rng.normal(size=(500, 2))
    a[100, 0], a[200, 1] = np.nan, np.inf
    f1, f2 = ManoeuvreFilter(), ManoeuvreFilter()
    o1 = np.array([f1.step(tt, aa) for tt, aa in zip(t, a)])
    o2 = np.array([f2.step_pair(tt, *aa) for tt, aa in zip(t, a)])
    np.testing.assert_array_equal(o1, o2)
    # vibration out: a 5 Hz, 0.4 m/s^2 shake leaves < 0.02 m/s^2 after the filter
    f3 = ManoeuvreFilter()
    tt = np.arange(0, 10, 0.01)
    out = np.array([f3.step_pair(x, 0.4 * np.sin(2 * np.pi * 5 * x), 0.0)[0] for x in tt])
    assert np.abs(out[300:]).max() < 0.02
