"""Entry-point groups: how an installed package adds a simulator, a gaze source or an arm to gazereg.

A package declares what it provides in its own pyproject.toml, with no code in gazereg naming it:

    [project.entry-points."gazereg.simulators"]
    mysim = "my_package.sim:SIMULATOR"            # a gazereg.envs.base.Simulator named "mysim"
    [project.entry-points."gazereg.gaze_sources"]
    mygaze = "my_package.gaze:MyGazeParams"       # a module that registers gaze source "mygaze" when imported
    [project.entry-points."gazereg.arms"]
    myarm = "my_package.arms:ARM"                 # a gazereg.training.arms.Arm named "myarm"

The entry point's name is the registered name. A registry asked for a name nobody registered looks it up in
its group (`load_plugin`), imports it and registers it, in whichever process asks, so the `gazereg` commands
and their worker processes all know it. Policies use the same mechanism in their own group
(`gazereg.policies`, see `gazereg.policies.plugins`).
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points

SIMULATORS = "gazereg.simulators"
GAZE_SOURCES = "gazereg.gaze_sources"
ARMS = "gazereg.arms"


def group_entry_points(group: str) -> list[EntryPoint]:
    """The installed packages' entry points in `group`."""
    return list(entry_points(group=group))


def plugin_names(group: str) -> list[str]:
    """The names installed packages provide in `group`, sorted."""
    return sorted({ep.name for ep in group_entry_points(group)})


def load_plugin(group: str, name: str, what: str) -> object | None:
    """The object the installed entry point `name` of `group` names (importing its module), or None when no
    installed package provides `name`. `what` names the kind in messages ("simulator", "gaze source").

    ImportError when the module fails to import; ValueError when several installed packages provide `name`
    differently."""
    found = {ep.value: ep for ep in group_entry_points(group) if ep.name == name}
    if not found:
        return None
    if len(found) > 1:
        raise ValueError(
            f"{what} {name!r} is provided by several installed packages ({sorted(found)}); uninstall all but one"
        )
    ep = next(iter(found.values()))
    try:
        return ep.load()
    except Exception as e:
        raise ImportError(
            f"{where(group, name, ep.value, what)} failed to load: {type(e).__name__}: {e}"
        ) from e


def where(group: str, name: str, value: str, what: str) -> str:
    """How messages name a plugin: `the simulator plugin toy = 'pkg.mod:SIM' (entry-point group ...)`."""
    return f"the {what} plugin {name} = {value!r} (entry-point group {group!r})"


def plugin_value(group: str, name: str) -> str:
    """The "module:attr" the installed entry point `name` of `group` names ("" when none does)."""
    return next((ep.value for ep in group_entry_points(group) if ep.name == name), "")
