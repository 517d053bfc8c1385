"""Faces of the Sidewalk cores for other ecosystems.

- ``sidewalk.interop.gymnasium``: ``sidewalk/Discrete-v0`` and ``sidewalk/Continuous-v0`` for ``gymnasium.make``
  and ``gymnasium.make_vec`` (registered on ``import sidewalk``);
- ``sidewalk.interop.safety_gymnasium``: ``sidewalk/SafetyDiscrete-v0`` and ``sidewalk/SafetyContinuous-v0``, the
  same envs with Safety-Gymnasium's ``(obs, reward, cost, terminated, truncated, info)`` step, built by its
  ``make``/``make_vec`` (registered when it is imported; Safety-Gymnasium itself is not needed);
- ``sidewalk.interop.pettingzoo``: ``parallel_env(domain=...)``, a PettingZoo ``ParallelEnv`` (needs the optional
  ``pettingzoo`` dependency: ``pip install 'sidewalk-problem[pettingzoo]'``).

Submodules are imported on demand, so importing this package pulls in neither gymnasium nor PettingZoo.
"""
