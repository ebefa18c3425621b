"""The compiled learning loops give the same classifier as the numpy implementation."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from follow.boost import kernels
from follow.boost.online_boosting import OnlineBoostingClassifier
from follow.ccf.features import FeatureMaps
from follow.config import IdentifyConfig


def _samples(n=8, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        maps = rng.random((16, 8, 4)) * 0.5
        maps[:8, :, 0] += 0.4 if i % 2 else 0.0  # odd samples: a brighter upper body
        out.append(FeatureMaps.from_maps(maps))
    return out


def _drive(clf, samples, steps):
    for i in range(steps):
        if i % 3 == 0:
            clf.train([samples[i % 8]], [samples[(i + 1) % 8], samples[(i + 3) % 8]])
        else:
            clf.update(samples[i % 8], 1 if i % 2 else -1)
    return clf


def _assert_same(a, b):
    np.testing.assert_array_equal(a.rects, b.rects)
    np.testing.assert_array_equal(a.best, b.best)
    np.testing.assert_allclose(a.alpha, b.alpha, rtol=1e-9)
    np.testing.assert_allclose(a.mean, b.mean, atol=1e-6)
    np.testing.assert_allclose(a.var, b.var, atol=1e-6)
    np.testing.assert_allclose(a.correct, b.correct, rtol=1e-9)
    samples = _samples(8, seed=1)
    np.testing.assert_allclose(a.confidence(samples), b.confidence(samples), atol=1e-9)


def test_numba_loops_match_numpy():
    pytest.importorskip("numba")
    samples = _samples()
    compiled = _drive(OnlineBoostingClassifier(4, IdentifyConfig(), compiled=True), samples, 150)
    plain = _drive(OnlineBoostingClassifier(4, IdentifyConfig(), compiled=False), samples, 150)
    assert compiled.is_trained
    _assert_same(compiled, plain)


def test_loops_match_numpy_uncompiled(monkeypatch):
    """The same loops run as plain Python (where numba is absent, they are not used)."""
    monkeypatch.setattr(kernels, "learn_step", kernels.python_learn_step)
    monkeypatch.setattr(kernels, "replace_step", kernels.python_replace_step)
    cfg = IdentifyConfig(num_selectors=5, weak_classifiers_per_selector=6)
    samples = _samples()
    loops = _drive(OnlineBoostingClassifier(4, cfg, compiled=True), samples, 30)
    plain = _drive(OnlineBoostingClassifier(4, cfg, compiled=False), samples, 30)
    _assert_same(loops, plain)


def test_compiled_without_numba_is_an_error(monkeypatch):
    monkeypatch.setattr(kernels, "learn_step", None)
    monkeypatch.setitem(sys.modules, "numba", None)  # as if not installed
    with pytest.raises(ValueError, match="compiled_boosting = false"):
        OnlineBoostingClassifier(4, IdentifyConfig(compiled_boosting=True))
    with pytest.raises(ValueError, match="numba"):
        OnlineBoostingClassifier(4, IdentifyConfig(), compiled=True)
    assert OnlineBoostingClassifier(4, IdentifyConfig())._kernel is None


def test_the_configuration_chooses_the_compiled_loops():
    pytest.importorskip("numba")
    assert OnlineBoostingClassifier(4, IdentifyConfig())._kernel is None
    compiled = OnlineBoostingClassifier(4, IdentifyConfig(compiled_boosting=True))
    assert compiled._kernel is kernels.learn_step is not None


def test_an_identifier_on_the_default_settings_does_not_load_numba():
    """numba's compiler stays resident once imported (about 105 MB): a process that has
    not asked for the compiled loops must not carry it. A fresh interpreter, since this
    one may have imported numba for another test."""
    script = (
        "import sys\n"
        "import numpy as np\n"
        "from follow.boost.online_boosting import OnlineBoostingClassifier\n"
        "from follow.ccf.features import FeatureMaps\n"
        "from follow.config import IdentifyConfig\n"
        "clf = OnlineBoostingClassifier(4, IdentifyConfig())\n"
        "maps = FeatureMaps.from_maps(np.random.default_rng(0).random((16, 8, 4)))\n"
        "clf.train([maps], [maps])\n"
        "print('numba' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == "False"
