"""Balancer registry: names as used by ``--balancer``, ``PUT /api/balancer`` and the viewer."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tessera.balancers.adaptive import AdaptiveBalancer
from tessera.balancers.adaptive_predict import AdaptivePredictBalancer
from tessera.balancers.base import Balancer
from tessera.balancers.eq_load import EqLoadBalancer
from tessera.balancers.grid import GridBalancer
from tessera.balancers.hetero import HeteroBalancer
from tessera.balancers.rotate import RotateBalancer
from tessera.balancers.rotate_predict import RotatePredictBalancer
from tessera.balancers.static import StaticBalancer
from tessera.balancers.tree_predict import TreePredictBalancer

BALANCERS: dict[str, type[Balancer]] = {cls.name: cls for cls in (
    StaticBalancer, AdaptiveBalancer, RotateBalancer, GridBalancer, HeteroBalancer, EqLoadBalancer,
    AdaptivePredictBalancer, RotatePredictBalancer, TreePredictBalancer)}


def create_balancer(name: str, params: Mapping[str, Any] | None = None) -> Balancer:
    """Instantiate a balancer by name; ValueError names the choices or the bad parameter."""
    try:
        cls = BALANCERS[name]
    except KeyError:
        raise ValueError(f"unknown balancer {name[:64]!r}; choose one of {sorted(BALANCERS)}") from None
    return cls(**dict(params or {}))
