"""benchmarks/compile_cost.py: JAX's compile-log messages parsed into stages."""

from __future__ import annotations

import pytest

from . import load_benchmark

compile_cost = load_benchmark("compile_cost")


def test_the_three_stages_of_a_program_are_read_from_jaxs_messages():
    assert compile_cost.stage_of("Finished tracing run_chunk for jit in 3.002278805 sec") == (
        "tracing", "run_chunk", pytest.approx(3.002278805))
    assert compile_cost.stage_of("Finished tracing + transforming run_chunk for pjit in 0.5 sec") == (
        "tracing", "run_chunk", pytest.approx(0.5))
    assert compile_cost.stage_of("Finished jaxpr to MLIR module conversion jit(run_chunk) in 1.28 sec") == (
        "jaxpr to MLIR module conversion", "run_chunk", pytest.approx(1.28))
    assert compile_cost.stage_of("Finished XLA compilation of jit(_threefry_split) in 0.365 sec") == (
        "XLA compilation", "_threefry_split", pytest.approx(0.365))
    assert compile_cost.stage_of("Compiling run_chunk with global shapes and types") is None
    assert set(compile_cost.STAGES) == {"tracing", "jaxpr to MLIR module conversion", "XLA compilation"}


def test_a_variant_is_a_name_or_name_and_json():
    assert compile_cost.parse_variant("no_closure") == ("no_closure", {"closure": False})
    assert compile_cost.parse_variant('far={"closure_radius_far": 8.0}') == ("far", {"closure_radius_far": 8.0})
    with pytest.raises(SystemExit, match="unknown variant"):
        compile_cost.parse_variant("nonsense")
