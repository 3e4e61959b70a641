"""Step functions are named without scanning ``sys.modules``: an import on another
thread (the plotting prefetch) cannot break the naming of a runner."""

from __future__ import annotations

import functools
import gc
import sys
import types

from jaxslam.runtime import executables


def test_name_survives_sys_modules_changing_mid_call():
    """A garbage collection inside the call runs a callback that imports a module, as
    JAX's gc callback hands the GIL to an importing thread; the name is unaffected."""
    from jaxslam.grid import driver, srupf

    added = []

    def importing(phase, info):
        if phase == "start":
            name = f"jaxslam_reliability_fake_{len(added)}"
            sys.modules[name] = types.ModuleType(name)
            added.append(name)

    threshold = gc.get_threshold()
    gc.callbacks.append(importing)
    gc.set_threshold(1, 1, 1)  # a collection at (nearly) every allocation of a container
    try:
        names = [executables.function_name(fn) for fn in (srupf.step, driver.summarise)]
    finally:
        gc.set_threshold(*threshold)
        gc.callbacks.remove(importing)
        for name in added:
            sys.modules.pop(name, None)
    assert names == ["jaxslam.grid.srupf:step", "jaxslam.grid.driver:summarise"]


def test_names_are_module_and_qualified_name():
    from jaxslam.grid import driver, srupf

    assert executables.function_name(srupf.step) == "jaxslam.grid.srupf:step"
    assert executables.function_name(driver.summarise) == "jaxslam.grid.driver:summarise"
    assert executables.function_name(None) == "None"
    # outside jaxslam, local, or not the object its name resolves to: no name
    assert executables.function_name(lambda x: x) is None
    assert executables.function_name(functools.reduce) is None

    def local(x):
        return x

    assert executables.function_name(local) is None
    impostor = functools.wraps(driver.summarise)(lambda info: info)  # a borrowed name
    assert executables.function_name(impostor) is None
    # a partial of a named function with plain arguments is named by them
    name = executables.function_name(functools.partial(srupf.step, config=3))
    assert name == "functools.partial(jaxslam.grid.srupf:step, config=3)"
    assert executables.function_name(functools.partial(srupf.step, object())) is None
    assert executables.function_name(functools.partial(lambda x: x, 1)) is None
