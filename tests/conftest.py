"""What the suite does when an optional piece is missing: skip on a developer's machine, fail in CI.

Markers (registered here):

* ``@pytest.mark.extension`` / ``@pytest.mark.extension("raster_forward")``: the test needs the
  compiled ``fracture_gs._C`` (with those attributes). Without it the test is skipped, unless
  ``FRACTURE_GS_REQUIRE_EXTENSION=1`` (``.ci/run`` sets it): then it fails, so a broken build
  can never pass CI as a wall of skips. Parametrise backends with :data:`BACKENDS`-style
  ``pytest.param("cpp", marks=pytest.mark.extension)`` so the ``reference`` variant still runs
  without the extension.
* ``@pytest.mark.mitsuba``: the test renders with Mitsuba 3; skipped without it, failed when
  ``CI=true``.

As a safety net, with ``FRACTURE_GS_REQUIRE_EXTENSION=1`` any skip whose reason mentions
``fracture_gs._C`` (a test with its own ``skipif``) is reported as a failure too.
"""
from __future__ import annotations

import os
from collections.abc import Iterator, Sequence

import pytest

REQUIRE_EXTENSION = "FRACTURE_GS_REQUIRE_EXTENSION"


def _env_flag(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() not in ("", "0", "false", "no")


def extension_required() -> bool:
    """True when a missing compiled extension must fail the tests (CI)."""
    return _env_flag(REQUIRE_EXTENSION)


def mitsuba_required() -> bool:
    """True when a missing Mitsuba must fail the tests (``CI=true``)."""
    return _env_flag("CI")


def extension_problem(attributes: Sequence[str] = ()) -> str | None:
    """Why the compiled extension cannot serve a test, or None when it can."""
    from fracture_gs._backend import compiled_module

    module = compiled_module()
    if module is None:
        return "fracture_gs._C is not built"
    missing = [name for name in attributes if not hasattr(module, name)]
    if missing:
        return f"fracture_gs._C is built without {', '.join(missing)}"
    return None


def mitsuba_problem() -> str | None:
    """Why Mitsuba 3 cannot render for a test, or None when it can."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return "Mitsuba 3 is not installed (pip install mitsuba==3.9.1)"
    return None


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "extension(*attributes): needs the compiled fracture_gs._C (with these "
        f"attributes); skipped without it, failed when {REQUIRE_EXTENSION}=1")
    config.addinivalue_line(
        "markers", "mitsuba: renders with Mitsuba 3; skipped without it, failed when CI=true")


def pytest_report_header(config: pytest.Config) -> list[str]:
    extension = extension_problem() or "fracture_gs._C is built"
    mitsuba = mitsuba_problem() or "Mitsuba 3 is installed"
    return [f"fracture_gs: {extension} ({REQUIRE_EXTENSION}="
            f"{'1: required' if extension_required() else 'unset: optional'}); {mitsuba} "
            f"({'required' if mitsuba_required() else 'optional'})"]


def _missing(problem: str | None, required: bool, how: str) -> None:
    if problem is None:
        return
    if required:
        pytest.fail(f"{problem}, and {how} requires it", pytrace=False)
    pytest.skip(problem)


def pytest_runtest_setup(item: pytest.Item) -> None:
    attributes = [name for marker in item.iter_markers("extension") for name in marker.args]
    if item.get_closest_marker("extension") is not None:
        _missing(extension_problem(attributes), extension_required(), f"{REQUIRE_EXTENSION}=1")
    if item.get_closest_marker("mitsuba") is not None:
        _missing(mitsuba_problem(), mitsuba_required(), "CI=true")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Iterator[None]:
    outcome = yield
    report = outcome.get_result()
    if report.skipped and extension_required() and isinstance(report.longrepr, tuple) and \
            "fracture_gs._C" in str(report.longrepr[2]):
        reason = str(report.longrepr[2]).removeprefix("Skipped: ")
        report.outcome = "failed"
        report.longrepr = (f"{item.nodeid}: skipped because {reason}, but "
                           f"{REQUIRE_EXTENSION}=1 requires the compiled extension")
