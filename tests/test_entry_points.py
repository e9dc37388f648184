"""The entry points kept between commands (i2pbench.registry.entry_points) are what importlib.metadata finds at every
step of installing, rewriting and removing a distribution, and are found anew only when one of those happened."""

import importlib
import importlib.metadata
import os
import shutil

import plugin_dists
import pytest

from i2pbench.registry import entry_points
from i2pbench.registry.entry_points import EntryPoint, installed

GROUP = "i2pbench"


@pytest.fixture
def scans(tmp_path, monkeypatch):
    """The cache in a fresh home, and a list that grows by one each time the entry points are found anew."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)  # else the cache would not move with HOME
    calls = []
    real = entry_points._find

    def find(group):
        calls.append(group)
        return real(group)

    monkeypatch.setattr(entry_points, "_find", find)
    return calls


def _truth() -> list[tuple[str, str, str, str]]:
    importlib.invalidate_caches()  # importlib.metadata's own listing of a folder changed within one clock tick
    eps = importlib.metadata.entry_points(group=GROUP)
    return sorted((ep.name, ep.value, ep.dist.version, ep.dist.metadata["Name"]) for ep in eps)


def _found() -> list[tuple[str, str, str, str]]:
    return sorted((ep.name, ep.value, ep.version, ep.distribution) for ep in installed(GROUP))


def test_entry_points_are_found_anew_exactly_when_a_distribution_is_installed_rewritten_or_removed(
    tmp_path, monkeypatch, scans
):
    site = plugin_dists.install(tmp_path / "site", {"one": "module_one"})
    monkeypatch.syspath_prepend(str(site))
    assert _found() == _truth() and ("one", "module_one", "0.1", "i2pbench-test-plugins") in _found()
    assert len(scans) == 1  # the second `_found` read the cache
    plugin_dists.install(site, {"two": "module_two"}, name="i2pbench-more-plugins")
    assert _found() == _truth() and "two" in {ep.name for ep in installed(GROUP)}
    assert len(scans) == 2
    (site / "i2pbench_test_plugins-0.1.dist-info" / "entry_points.txt").write_text("[i2pbench]\none = renamed:obj\n")
    assert _found() == _truth() and ("one", "renamed:obj") in {(ep.name, ep.value) for ep in installed(GROUP)}
    shutil.rmtree(site / "i2pbench_more_plugins-0.1.dist-info")
    assert _found() == _truth() and "two" not in {ep.name for ep in installed(GROUP)}
    assert len(scans) == 4


def test_the_script_and_python_m_share_the_cache_and_other_paths_do_not(tmp_path, monkeypatch, scans):
    installed(GROUP)
    monkeypatch.syspath_prepend(str(tmp_path))  # a folder holding no distribution, as the script's or the current one
    installed(GROUP)
    assert len(scans) == 1
    monkeypatch.syspath_prepend(str(tmp_path / "missing"))  # an entry that is no folder (nor a zip yet)
    installed(GROUP)
    assert len(scans) == 2


def test_a_cache_that_cannot_be_written_or_read_costs_only_the_scan(tmp_path, monkeypatch, scans):
    (tmp_path / "home").write_text("a file, not a folder")
    assert _found() == _truth()
    monkeypatch.setenv("HOME", str(tmp_path / "other"))
    installed(GROUP)
    (cache,) = (tmp_path / "other" / ".cache" / "i2pbench").iterdir()
    cache.write_text("{not json")
    assert _found() == _truth()
    assert len(scans) == 3 and os.listdir(cache.parent) == [cache.name]  # rewritten whole, no temporary left


def test_xdg_cache_home_moves_the_cache_and_a_relative_one_is_ignored(tmp_path, monkeypatch, scans):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _found() == _truth() and _found() == _truth()
    assert len(scans) == 1  # the second `_found` read the cache, from the XDG folder
    (cache,) = (tmp_path / "xdg" / "i2pbench").iterdir()
    assert cache.name.startswith("entry-points-") and not (tmp_path / "home").exists()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CACHE_HOME", "relative")  # not absolute: the XDG rule says ignore it
    installed(GROUP)
    assert len(scans) == 2 and (tmp_path / "home" / ".cache" / "i2pbench").is_dir()
    assert not (tmp_path / "relative").exists()


def test_without_a_home_folder_the_cache_is_skipped_unless_xdg_cache_home_names_one(tmp_path, monkeypatch, scans):
    monkeypatch.delenv("HOME")
    monkeypatch.setattr(os.path, "expanduser", lambda path: path)  # as when neither HOME nor a passwd entry exists
    assert _found() == _truth() and _found() == _truth()
    assert len(scans) == 2  # nowhere to keep them: found anew each time
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    installed(GROUP)
    installed(GROUP)
    assert len(scans) == 3 and len(list((tmp_path / "xdg" / "i2pbench").iterdir())) == 1


@pytest.mark.parametrize(
    ("value", "expected"),
    [("os.path", os.path), ("os.path:join", os.path.join), ("os:path.join", os.path.join), ("os:sep [extra]", os.sep)],
)
def test_an_entry_point_loads_what_importlib_metadata_would(value, expected):
    assert EntryPoint("x", value, "1", "d").load() is expected
    assert importlib.metadata.EntryPoint("x", value, GROUP).load() is expected


def test_a_value_that_is_no_object_reference_fails_to_load():
    with pytest.raises(ValueError, match="no object reference"):
        EntryPoint("x", "not a reference!", "1", "d").load()
