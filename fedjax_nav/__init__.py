"""fedjax_nav: JAX-accelerated federated deep RL for robot navigation.

Importing the package registers its gymnasium env (`GYM_ENV_ID`, docs/gym.md) without importing
gymnasium or jax: where gymnasium is already imported it is registered at once, otherwise when
gymnasium is first imported (a one-shot import hook). Importing gymnasium costs ~0.2-0.45 s
(numpy included), which `import fedjax_nav` and `fedjax-nav --help` do not pay. So, after
`import fedjax_nav`, `gymnasium.make("fedjax_nav/Nav-v0")` works in either import order, and
gymnasium's convention `gymnasium.register_envs(fedjax_nav)` too.
"""

from __future__ import annotations

import sys

__version__ = "0.1.0"

GYM_ENV_ID = "fedjax_nav/Nav-v0"
GYM_ENTRY_POINT = "fedjax_nav.env.gym_env:NavGymEnv"
GYM_VECTOR_ENTRY_POINT = "fedjax_nav.env.gym_vector:NavVectorEnv"


def register_gymnasium() -> None:
    """Register `GYM_ENV_ID` with gymnasium (entry points as strings: nothing of jax is imported
    until an env is made); a second call is a no-op. No `max_episode_steps`: the env's own
    `episode_length` truncates."""
    import gymnasium

    if GYM_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=GYM_ENV_ID, entry_point=GYM_ENTRY_POINT, vector_entry_point=GYM_VECTOR_ENTRY_POINT)


class _RegisterWhenGymnasiumIsImported:
    """A `sys.meta_path` finder that, once, finds gymnasium as the other finders do and runs
    `register_gymnasium` right after gymnasium's own module has run."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)  # one-shot; also keeps the lookup below from coming back here
        import importlib.util

        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
            spec.loader = _ThenRegister(spec.loader)
        return spec


class _ThenRegister:
    """A loader that runs `loader` and then registers the env."""

    def __init__(self, loader):
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        self.loader.exec_module(module)
        register_gymnasium()

    def __getattr__(self, name):  # get_resource_reader, is_package, ...: the loader's own
        return getattr(self.loader, name)


if "gymnasium" in sys.modules:
    register_gymnasium()
elif not any(isinstance(f, _RegisterWhenGymnasiumIsImported) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWhenGymnasiumIsImported())
