"""`vogjax config`: the settings file of `vogjax map` or `vogjax explore`, with every default,
and a check of one."""

from __future__ import annotations

import argparse
from pathlib import Path

from vogjax.commands.common import add_output_flags
from vogjax.commands.simulation import scene_help, scene_names

COMMANDS = ("map", "explore")

DESCRIPTION = """\
Print the settings file of `vogjax map` (or, with --for explore, of `vogjax explore`) with every
setting at its default: each table headed by what its settings do, each setting with what it
accepts (its bounds) and its unit. The file is built from the settings' declared rules
(vogjax/config), so it always lists exactly what --config accepts, and passing it back
unchanged gives the defaults. Keep only the lines you change, or all of them.

--check FILE reads a settings file as the command would, and prints the settings in it that
differ from the defaults; a file with an unknown table or setting, a wrong type or a value out
of bounds is refused with one line naming the setting (exit 2)."""

EPILOG = """\
examples:
  vogjax config --defaults > settings.toml
  vogjax config --defaults --preset paper > paper.toml
  vogjax config --defaults --for explore > explore.toml
  vogjax config --defaults --for explore --rule papers --scene tank > tank_papers.toml
  vogjax config --check settings.toml"""


def add_parser(commands) -> None:
    """Declare `vogjax config` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    from vogjax.config.pipeline import PRESETS

    config = commands.add_parser(
        "config",
        help="print the settings file with every default, or check one",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    what = config.add_mutually_exclusive_group(required=True)
    what.add_argument("--defaults", action="store_true", help="print every setting at its default (TOML)")
    what.add_argument("--check", type=Path, metavar="FILE", help="check a settings file")
    config.add_argument(
        "--for", dest="command_for", choices=COMMANDS, default="map", help="the command whose settings these are"
    )
    config.add_argument(
        "--preset",
        choices=PRESETS,
        default="default",
        help="with --for map: the settings to start from, as `vogjax map --preset`",
    )
    config.add_argument(
        "--rule",
        choices=("time", "papers"),
        default="time",
        help="with --for explore: the planner rule, as `vogjax explore --rule`; the time-aware rule's settings are "
        "the same for every scene, the papers' depend on it",
    )
    config.add_argument(
        "--scene",
        choices=scene_names(ground=False),
        default=None,
        help=f"with --for explore --rule papers: the scene whose planner settings to print "
        f"({scene_help(ground=False)}); by default none, and [planner] is printed commented out, since the papers' "
        "settings are the scene's",
    )
    add_output_flags(config)


def run(args: argparse.Namespace) -> None:
    """Print the settings file, or check one and print what it changes.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax config`.
    """
    if args.command_for == "map" and (args.scene is not None or args.rule != "time"):
        raise ValueError("--scene and --rule are for --for explore (the planner's settings)")
    if args.scene is not None and args.rule != "papers":
        raise ValueError("--scene is for --rule papers (the time-aware rule's settings are the same for every scene)")
    if args.command_for == "explore" and args.preset != "default":
        raise ValueError("--preset is for --for map (`vogjax explore` has no presets)")
    if args.defaults:
        print(defaults_text(args.command_for, args.preset, args.scene, args.rule), end="")
    else:
        print(check_text(args.check, args.command_for, args.preset, args.scene, args.rule))


def default_settings(command: str, preset: str = "default", scene: str | None = None, rule: str = "time"):
    """The settings a command uses when its settings file sets nothing.

    Parameters
    ----------
    command : str
        "map" or "explore".
    preset : str
        `vogjax map`'s --preset ("default" or "paper").
    scene : str or None
        `vogjax explore`'s scene: its planner settings under `rule` (None: PlannerConfig's defaults).
    rule : str
        `vogjax explore`'s --rule ("time" or "papers").

    Returns
    -------
    JobConfig or ExploreConfig
        The settings.
    """
    from vogjax.config import JobConfig
    from vogjax.config.planner import ExploreConfig, PlannerConfig

    if command == "map":
        return JobConfig.preset(preset)
    return ExploreConfig(planner=_scene_planner(scene, rule) if scene else PlannerConfig())


def _scene_planner(scene: str, rule: str):
    from vogjax.sim.explore import scene_planner  # MJX and JAX: only when a scene is named

    return scene_planner(scene, rule=rule)


def defaults_text(command: str, preset: str = "default", scene: str | None = None, rule: str = "time") -> str:
    """The settings file of a command with every setting at its default.

    Parameters
    ----------
    command : str
        "map" or "explore".
    preset : str
        `vogjax map`'s --preset.
    scene : str or None
        `vogjax explore`'s scene, with rule "papers" (None: [planner] written commented out).
    rule : str
        `vogjax explore`'s --rule.

    Returns
    -------
    str
        TOML text that `--config` reads back to `default_settings(command, preset, scene, rule)`.
    """
    from vogjax.config.settings_file import settings_toml

    config = default_settings(command, preset, scene, rule)
    if command == "map":
        title = "vogjax map" + (f" --preset {preset}" if preset != "default" else "")
        return settings_toml(config, title)
    if rule == "time":
        note = "The time-aware rule's settings, the same for every scene. --seed, when given, sets the seed."
        return settings_toml(config, "vogjax explore", notes={"planner": note})
    if scene is None:
        note = (
            "With --rule papers the planner's settings are the scene's (the papers' for it): the lines below, "
            "PlannerConfig's own defaults, are comments; `vogjax config --defaults --for explore --rule papers "
            "--scene NAME` prints a scene's. --seed, when given, sets the seed."
        )
        return settings_toml(config, "vogjax explore --rule papers", commented=("planner",), notes={"planner": note})
    note = f"The papers' planner settings for the {scene} scene. --seed, when given, sets the seed."
    return settings_toml(config, f"vogjax explore --rule papers --scene {scene}", notes={"planner": note})


def check_text(path: Path, command: str, preset: str = "default", scene: str | None = None, rule: str = "time") -> str:
    """Read a settings file as `command` would; a line saying what it changes.

    Parameters
    ----------
    path : Path
        The settings file.
    command : str
        "map" or "explore".
    preset : str
        `vogjax map`'s --preset: the settings the file starts from.
    scene : str or None
        `vogjax explore`'s scene.
    rule : str
        `vogjax explore`'s --rule.

    Returns
    -------
    str
        "FILE: valid settings for `vogjax map`; ..." and the settings that differ from the
        defaults, one per line.

    Raises
    ------
    ValueError
        Naming the file, or the table or setting at fault.
    """
    from vogjax.config.settings_file import differences

    base = default_settings(command, preset, scene, rule)
    config = type(base).from_toml(path, base)  # what the file sets, over the defaults
    changed = differences(config, base)
    head = f"{path}: valid settings for `vogjax {command}`"
    if not changed:
        return f"{head}; every setting at its default"
    return f"{head}; {len(changed)} differ from the defaults:\n" + "\n".join(f"  {line}" for line in changed)
