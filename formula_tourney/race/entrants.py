"""A race's entrants: trained models from their checkpoints, and bots, each with its env config.

A model races with the observation it was trained on: its run spec's env settings, reference
line and LAC on the race track (``training.envs.RunEnvs``, the one way a run's env is built).
Its actor's input size says whether it was trained with the opponent block (base + 36 values)
or without (base: it drives blind to the others, and the race table marks it); any other size
is an error. Bots get the race's shared settings (those of the first model, else defaults).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from formula_tourney.bots.race_bot import race_bot
from formula_tourney.errors import UserInputError
from formula_tourney.race.drivers import Driver, ModelDriver
from formula_tourney.sim.config import EnvConfig, EnvSettings
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.sim.sensors import observation_names
from formula_tourney.sim.track import Track
from formula_tourney.training.checkpoint import load_run_checkpoint
from formula_tourney.training.envs import RunEnvs


@dataclass
class Entrant:
    """One car's driver and settings; ``make_driver`` gives a fresh driver for each race."""

    name: str
    kind: str  # "model" | "bot"
    config: EnvConfig
    make_driver: Callable[[], Driver]
    sees_opponents: bool
    source: str = ""


def model_entrant(path: str | Path, track_name: str, name: str | None = None) -> Entrant:
    """The model of checkpoint ``path`` as an entrant on the catalog track ``track_name``."""
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"checkpoint {path}: no such file")
    agent, spec, _ = load_run_checkpoint(path)
    config = RunEnvs(spec, extra_tracks=[track_name]).config(track_name, test=True)
    base = len(observation_names(config.lac, config.lac_distances_m))
    if agent.obs_dim == base:
        sees = False
    elif agent.obs_dim == base + RK.N_OPP:
        sees = True
    else:
        raise UserInputError(
            f"checkpoint {path}: its actor takes {agent.obs_dim} values per observation, but "
            f"its run spec's telemetry has {base} ({base + RK.N_OPP} with the opponent block)")
    label = name or _default_name(path, spec.variant)
    return Entrant(label, "model", config,
                   lambda: ModelDriver(label, agent, sees, str(path)), sees, str(path))


def _default_name(path: Path, variant: str) -> str:
    """``<entrant>/seed-<n>`` for a checkpoint in a job folder (``.../<entrant>/seed-<n>/
    checkpoints/<file>``), else the run's variant."""
    parts = path.resolve().parts
    if len(parts) >= 4 and parts[-2] == "checkpoints" and parts[-3].startswith("seed-"):
        return f"{parts[-4]}/{parts[-3]}"
    return variant


def bot_entrant(kind: str, track: Track, settings: EnvSettings | None,
                name: str | None = None) -> Entrant:
    """A bot on ``track`` with the race's shared env settings (``bots.race_bot``)."""
    bot = race_bot(kind, track, settings, name)
    return Entrant(bot.name, "bot", bot.config, bot.make_driver, False, bot.source)


def build_entrants(models: Sequence[str | Path], bots: Sequence[str], track: Track,
                   track_name: str) -> list[Entrant]:
    """Models first (in the order given), then bots; names made unique with ``#2``, ``#3``.
    ``track_name`` is how the catalog knows ``track`` (the models' run specs load it by it)."""
    if not models and not bots:
        raise UserInputError("a race needs at least one model or bot")
    entrants = [model_entrant(m, track_name) for m in models]
    shared = None
    if entrants:
        first = entrants[0].config
        shared = EnvSettings(**{k: getattr(first, k) for k in EnvSettings.model_fields})
    entrants += [bot_entrant(b, track, shared) for b in bots]
    seen: dict[str, int] = {}
    for e in entrants:
        seen[e.name] = seen.get(e.name, 0) + 1
        if seen[e.name] > 1:
            e.name = f"{e.name}#{seen[e.name]}"
    return entrants
