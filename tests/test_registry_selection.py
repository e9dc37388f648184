"""The default registry follows the environment's plugin selection: a test or command that loads no plugin for a
while never leaves its empty registry to the next caller (the order-dependent failures issue 38 names)."""

from i2pbench.registry.build import default_registry


def test_the_default_registry_is_the_one_of_the_current_selection(monkeypatch):
    everything = default_registry()
    assert "canny" in everything.components["extractor2d"]

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    nothing = default_registry()
    assert len(nothing.components["extractor2d"]) == 0 and not nothing.plugins
    assert default_registry() is nothing  # built once per selection

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "classic")
    classic = default_registry()
    assert "canny" in classic.components["extractor2d"] and "superpoint-cnn" not in classic.components["encoder2d"]

    monkeypatch.delenv("I2PBENCH_LOAD_PLUGINS")
    assert default_registry() is everything
