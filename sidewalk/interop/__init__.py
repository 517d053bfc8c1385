"""Faces of the Sidewalk cores for other ecosystems.

- ``sidewalk.interop.gymnasium``: ``sidewalk/Discrete-v0`` and ``sidewalk/Continuous-v0`` for ``gymnasium.make``
  and ``gymnasium.make_vec`` (registered on ``import sidewalk``);
- ``sidewalk.interop.pettingzoo``: ``parallel_env(domain=...)``, a PettingZoo ``ParallelEnv`` (needs the optional
  ``pettingzoo`` dependency: ``pip install 'sidewalk[pettingzoo]'``).

Submodules are imported on demand, so importing this package pulls in neither gymnasium nor PettingZoo.
"""
