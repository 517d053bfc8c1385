"""The one place where sidewalk touches OmegaConf's internals: the key of the node a resolver is resolving.

A resolver that declares ``_node_`` gets the config node holding the interpolation, and OmegaConf's public API offers
no way to ask that node its own key; its private ``_key()`` answers. OmegaConf may rename it in any release:
``node_key`` checks it exists and raises a ``RuntimeError`` naming the OmegaConf version (as
``tests/test_adapters.py`` does), never a silently wrong value. Checked against OmegaConf 2.3.
"""

from __future__ import annotations

from typing import Any

import omegaconf


def node_key(node: Any) -> Any:
    """The key of ``node`` in its parent (a resolver's ``_node_``): ``width_m`` for ``env.width_m``."""
    try:
        key = node._key
    except AttributeError:
        raise RuntimeError(
            f"OmegaConf {omegaconf.__version__}: {type(node).__name__} has no _key(), which sidewalk's resolvers use "
            "to learn which key they resolve; sidewalk/_omegaconf.py needs updating for this OmegaConf version"
        ) from None
    return key()
