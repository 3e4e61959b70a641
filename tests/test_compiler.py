"""jaxslam's XLA compiler options (jaxslam.compiler): what options() returns, and that
jit applies them and keeps them on the jitted function."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam import compiler


def test_options_default_environment_and_xla_flags(monkeypatch):
    monkeypatch.delenv(compiler.ENV_VAR, raising=False)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    assert compiler.options() == compiler.OPTIONS == {"xla_cpu_use_fusion_emitters": False}
    assert compiler.options() is not compiler.OPTIONS  # a copy: callers cannot change the defaults
    monkeypatch.setenv(compiler.ENV_VAR, "xla")
    assert compiler.options() == {}
    monkeypatch.setenv(compiler.ENV_VAR, " JAXSLAM ")
    assert compiler.options() == compiler.OPTIONS
    monkeypatch.setenv(compiler.ENV_VAR, "fast")
    with pytest.raises(ValueError, match="JAXSLAM_XLA_OPTIONS.*'fast'"):
        compiler.options()
    monkeypatch.delenv(compiler.ENV_VAR)
    # An option that XLA_FLAGS sets is left to XLA_FLAGS.
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true --xla_force_host_platform_device_count=1")
    assert compiler.options() == {}
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=1")
    assert compiler.options() == compiler.OPTIONS


def test_jit_applies_and_records_options(monkeypatch):
    monkeypatch.delenv(compiler.ENV_VAR, raising=False)
    monkeypatch.delenv("XLA_FLAGS", raising=False)

    def f(x, n):
        return jnp.cumsum(jnp.sin(x)) * n

    jitted = compiler.jit(f, static_argnames=("n",))
    assert jitted.jaxslam_compiler_options == compiler.OPTIONS
    x = jnp.linspace(0.0, 3.0, 50, dtype=jnp.float32)
    np.testing.assert_array_equal(np.asarray(jitted(x, n=2)), np.asarray(f(x, 2)))
    decorated = compiler.jit(static_argnames=("n",))(f)
    np.testing.assert_array_equal(np.asarray(decorated(x, n=3)), np.asarray(f(x, 3)))
    # A caller's options are added to (and override) jaxslam's.
    merged = compiler.jit(f, static_argnames=("n",), compiler_options={"xla_cpu_use_fusion_emitters": True})
    assert merged.jaxslam_compiler_options == {"xla_cpu_use_fusion_emitters": True}
    np.testing.assert_array_equal(np.asarray(merged(x, n=2)), np.asarray(f(x, 2)))
    # An unknown option is XLA's error, not silently ignored.
    with pytest.raises(Exception, match="no_such_option"):
        compiler.jit(f, static_argnames=("n",), compiler_options={"xla_no_such_option": 1})(x, n=1)
    monkeypatch.setenv(compiler.ENV_VAR, "xla")
    assert compiler.jit(f, static_argnames=("n",)).jaxslam_compiler_options == {}
    # jit_with: exactly the given options, jaxslam's not added
    assert compiler.jit_with(f, None, static_argnames=("n",)).jaxslam_compiler_options == {}
    monkeypatch.delenv(compiler.ENV_VAR)
    exact = compiler.jit_with(f, {}, static_argnames=("n",))
    assert exact.jaxslam_compiler_options == {}
    np.testing.assert_array_equal(np.asarray(exact(x, n=2)), np.asarray(f(x, 2)))
