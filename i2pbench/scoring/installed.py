"""What scores a run here: the metrics in force (i2pbench's own, `metrics.BUILTIN`, then those a registry's plugins
register) and what the store, boards and training validation compute from them; the registered protocol cards (the
default is in every registry), the Protocol a run is made under (it holds its card's rules), a stored run's
Protocol read back with its card's rules, and records scored under those rules."""

from __future__ import annotations

import copyreg
import difflib
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ..errors import I2PBenchError
from ..registry import build
from .cards import DEFAULT_NAME, DEFAULT_VERSION, ProtocolCard
from .metrics import BUILTIN, Metric, Scored
from .protocol import Protocol
from .score import frame_errors

if TYPE_CHECKING:
    from ..registry.catalog import Registry


def active(registry: Registry | None = None) -> tuple[Metric, ...]:
    """The built-in metrics, then those the registry's plugins register (in plugin order); default: the installed
    plugins' registry."""
    return BUILTIN + tuple((registry or build.default_registry()).metrics.values())


def named(name: str) -> Metric:
    """The installed metric called `name`: how a metric crosses to a worker process, where the plugins the
    environment selects are loaded again (its callables are often lambdas, which do not pickle)."""
    metric = by_name().get(name)
    if metric is None:
        raise I2PBenchError(f"metric {name!r} is not installed in this process (a plugin given to the registry by "
                            "hand, not by entry point?): run it with the in-process executor")  # fmt: skip
    return metric


copyreg.pickle(Metric, lambda metric: (named, (metric.name,)))


def record_values(scored: Scored, metrics: Iterable[Metric] | None = None) -> dict[str, float]:
    """A frame's per-frame metrics, as its record stores them."""
    return {m.name: m.frame(scored) for m in (active() if metrics is None else metrics) if m.frame is not None}


def aggregates(records: pd.DataFrame, protocol: Protocol, metrics: Iterable[Metric] | None = None) -> dict[str, Any]:
    """A row's aggregates by metric name (stds as `Metric.std`): what training validation reports."""
    out: dict[str, Any] = {}
    for metric in active() if metrics is None else metrics:
        if metric.column is None:
            continue
        values = metric.per_frame(records, protocol)
        out[metric.name] = metric.reduce(values)
        if metric.std:
            kept = pd.Series(values, dtype=float).dropna()
            out[metric.std] = float(kept.std(ddof=0)) if len(kept) else np.nan
    return out


def by_name(metrics: Iterable[Metric] | None = None) -> dict[str, Metric]:
    return {m.name: m for m in (active() if metrics is None else metrics)}


def installed(registry=None) -> dict[str, ProtocolCard]:
    """Every registered card by name, the default first (a registry holds it even when every plugin is blocked)."""
    return dict((registry or build.default_registry()).protocols)


def find(name: str, registry=None) -> ProtocolCard:
    """The card registered as `name`; an unknown name suggests the closest."""
    cards = installed(registry)
    if name in cards:
        return cards[name]
    close = difflib.get_close_matches(name, list(cards), n=1, cutoff=0.5)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise I2PBenchError(f"unknown protocol {name!r}{hint} (known: {', '.join(cards)})")


def of(protocol: Protocol, registry=None) -> ProtocolCard:
    """The card a run's Protocol was made from, refused when the installed card has another version."""
    card = find(protocol.name, registry)
    if card.version != protocol.version:
        raise I2PBenchError(f"the run was made under protocol {protocol.name} v{protocol.version}; the installed "
                            f"card is v{card.version}: evaluate it with the i2pbench that has that card")  # fmt: skip
    return card


def read_back(card: dict, registry=None) -> Protocol:
    """A stored run's Protocol from its card, holding the rules of the installed card it names (refused when that
    card is unknown here or has another version): the card's thresholds and RRE kind are stored, the rest of its
    rules (failures, the frames left out, the std's ddof) are the card's."""
    protocol = Protocol.from_card(card)
    if (protocol.name, protocol.version) == (DEFAULT_NAME, DEFAULT_VERSION):
        return protocol
    return Protocol.from_card(card, of(protocol, registry).rules)


def for_run(name: str, seed: int, dataset: str, registry=None) -> Protocol:
    """The Protocol `run --protocol NAME` runs under; refused, listing each input, when i2pbench cannot give the
    card's stages what its paper gave them (a run would otherwise be scored as that paper's while fed otherwise)."""
    card = find(name, registry)
    unmet = card.unmet(dataset)
    if unmet:
        lines = "\n  ".join(unmet)
        raise I2PBenchError(
            f"protocol {card.name} v{card.version} ({card.paper}) needs inputs i2pbench cannot give its stages on "
            f"{dataset} yet, so nothing was run:\n  {lines}\nto score an existing run by its scoring rules alone: "
            f"i2pbench evaluate RUN_DIR --rules {card.name} --rules-only"
        )
    return card.protocol(seed, dataset)


def rescored(records: pd.DataFrame, protocol: Protocol) -> pd.DataFrame:
    """The records as the protocol's card scores them: under the default card unchanged; under another, rte_m and
    rre_deg by its rules and the frames it leaves out (skipped failures, DeepI2P's all-inlier frames) dropped, so
    the leaderboard's metrics (thresholds from the same card) give its Acc., means and stds."""
    if (protocol.name, protocol.version) == (DEFAULT_NAME, DEFAULT_VERSION) or records.empty:
        return records
    errors = frame_errors(records, protocol.rules)
    return records.assign(rte_m=errors["rte"], rre_deg=errors["rre"])[errors["scored"]]
