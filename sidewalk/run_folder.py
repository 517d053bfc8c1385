"""A run folder that describes exactly the run that made it: atomic files, two checkpoint generations, a resume
that refuses a different config, a history of every start, and a finished folder that keeps only what is small.

Files (see ``sidewalk.experiment`` for what the trial writes into them):

- ``config.yaml``: the resolved config, written once when the run starts and never changed by a resume except
  for a larger ``iterations``;
- ``history.jsonl``: one line per event (started, resumed with what changed, interrupted, diverged, finished);
- ``checkpoint.pt`` and ``checkpoint.prev.pt``: the newest full state and the one before it; a checkpoint that
  cannot be read is named in a warning and the previous one is used;
- ``policy.pt``: the learner's networks only (no optimiser, no replay buffer), all a report or a render needs;
  with ``keep_checkpoint=final`` (the default) it is all that stays of the state once the run has finished;
- ``.writer.lock``: the lock of the one process that writes the folder (``writer_lock``) and who it is.

A group folder (``replicas=R``) holds one ordinary run folder per seed, ``seed<S>/`` (``replica_dir``), beside
``.group/`` (the group's own config, history and checkpoint). Commands that take many runs read it as its seed
folders (``seed_folders``); one that needs one run names them (``one_run_folder``).

Every ``.pt`` file is read back through ``read_torch_file``, which builds tensors and plain data only: a file
someone sent cannot run code.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import math
import os
import pickle
import re
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omegaconf import OmegaConf

if TYPE_CHECKING:
    from sidewalk.world import World

CONFIG = "config.yaml"
HISTORY = "history.jsonl"
CHECKPOINT = "checkpoint.pt"
PREVIOUS_CHECKPOINT = "checkpoint.prev.pt"
POLICY = "policy.pt"
BEST_POLICY = "policy.best.pt"  # the policy of the run's best evaluation, which its absolute metric re-evaluates
METRICS = "metrics.csv"
# A committed reference run's metrics (sidewalk.reference collect): compressed, float32 precision, read like METRICS.
METRICS_COMPRESSED = "metrics.csv.xz"
SUMMARY = "summary.json"
LOCK = ".writer.lock"
# In a folder of replicas trained together (replicas=R, sidewalk.experiment.Trial): the group's own config, history and checkpoint.
GROUP_DIR = ".group"
# Keys a resume may change: the flag itself and what is kept after the run, neither of which changes a number.
RESUME_MAY_CHANGE = ("resume", "keep_checkpoint", "plots")


def replica_dir(run_dir: str | Path, seed: int) -> Path:
    """Where seed ``seed`` of a group (a run of several seeds, ``replicas=R``) writes its run folder."""
    return Path(run_dir) / f"seed{seed}"


def group_state_dir(run_dir: str | Path, replicas: int) -> Path:
    """Where a run of ``replicas`` seeds keeps its config, history and checkpoint: ``run_dir`` for one seed, its
    ``.group/`` for several."""
    return Path(run_dir) if replicas == 1 else Path(run_dir) / GROUP_DIR


def group_seed_dirs(run_dir: str | Path, seed: int, replicas: int) -> list[Path]:
    """Each seed's run folder in a run of seeds ``seed .. seed+replicas-1``: ``run_dir`` itself for one seed,
    ``run_dir/seed<S>/`` each for several."""
    if replicas == 1:
        return [Path(run_dir)]
    return [replica_dir(run_dir, seed + replica) for replica in range(replicas)]


def is_group_folder(path: str | Path) -> bool:
    """Whether ``path`` is a group folder: the folder of a run of several seeds, holding ``.group/``."""
    return (Path(path) / GROUP_DIR).is_dir()


def seed_folders(path: str | Path) -> list[Path]:
    """The seeds' run folders of the group folder ``path`` (``replica_dir``), in seed order; [] for any other
    folder (or a group killed before its seeds' folders were made)."""
    if not is_group_folder(path):
        return []
    seeds = sorted(int(match[1]) for child in Path(path).iterdir()
                   if child.is_dir() and (match := re.fullmatch(r"seed(\d+)", child.name)))
    return [replica_dir(path, seed) for seed in seeds]


def one_run_folder(path: str | Path, shown: str | None = None) -> Path:
    """``path`` as the one run a command needs (``shown``: how the message shows it, ``opponent.path='...'``; by
    default the path); a group folder raises ``GroupFolderGiven`` naming its seeds' folders to choose from."""
    if not is_group_folder(path):
        return Path(path)
    seeds = seed_folders(path)
    choose = (f"give one of its {len(seeds)} seeds' run folders: {', '.join(map(str, seeds))}" if seeds
              else "none of its seeds' run folders has been made yet")
    raise GroupFolderGiven(f"{shown or path} is a group folder (several seeds trained together, replicas=R) and "
                           f"one run is needed here: {choose}")


def write_compressed_metrics(metrics: Any, folder: Path) -> None:
    """Write a metrics table (a pandas DataFrame) as ``METRICS_COMPRESSED``: nine significant digits keep every
    float32 value, xz keeps a 5000-iteration run to a few hundred kilobytes."""
    atomic_write(Path(folder) / METRICS_COMPRESSED,
                 lambda tmp: metrics.to_csv(tmp, index=False, float_format="%.9g", compression="xz"))


class RunFolderError(RuntimeError):
    """A run folder that cannot be read, started or continued as asked (the message says why and what to do)."""


class UnreadableFile(RunFolderError, ValueError):
    """A file read back from a run folder that is torn, corrupt, or not a torch file (a ValueError too: a bad
    input, which every runner reports as one ``error:`` line)."""

    def __init__(self, path: Path, detail: str) -> None:
        self.path, self.detail = path, detail
        super().__init__(f"{path} is unreadable ({detail})")


class UnsafeFile(UnreadableFile):
    """A file read back that holds objects other than tensors, plain data and the few safe types checkpoints use:
    refused before any of it is built, so nothing in it runs."""

    def __init__(self, path: Path, held: list[str]) -> None:
        self.path, self.held = path, held
        self.detail = f"it holds {', '.join(held)}"
        RunFolderError.__init__(
            self,
            f"{path} holds {', '.join(held)}: a sidewalk file holds only tensors and plain data, so it was refused and "
            "nothing in it ran. Load it by hand only if you trust its author (torch.load(weights_only=False))",
        )


class GroupFolderGiven(RunFolderError, ValueError):
    """A group folder given where one run is needed (the message names its seeds' folders): a ValueError too, a bad
    input that every runner reports as one ``error:`` line."""


class FolderInUse(RunFolderError):
    """Another live process writes the run folder (it holds the folder's lock)."""


_held: dict[Path, tuple[int, int]] = {}  # run folder -> (lock file descriptor, nesting depth) held by this process


@contextlib.contextmanager
def writer_lock(run_dir: Path) -> Iterator[None]:
    """Hold ``run_dir``'s writer lock for the block: an OS file lock (``flock``) on ``.writer.lock``, which the
    kernel releases when the process ends in any way, so a killed writer leaves no stale lock. The file names the
    holder (pid, host, start time) for the refusal another process gets: ``FolderInUse``, before any compute.
    Re-entrant within a process (the runner takes it before its checks, the trial again around its loop)."""
    key = Path(run_dir).resolve()
    if key in _held:
        descriptor, depth = _held[key]
        _held[key] = (descriptor, depth + 1)
        try:
            yield
        finally:
            _held[key] = (descriptor, _held[key][1] - 1)
        return
    key.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(key / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.read(descriptor, 4096).decode(errors="replace").strip()
        os.close(descriptor)
        raise FolderInUse(_in_use_message(key, holder)) from None
    holder = {"pid": os.getpid(), "host": socket.gethostname(),
              "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds")}
    os.ftruncate(descriptor, 0)
    os.pwrite(descriptor, json.dumps(holder).encode(), 0)
    _held[key] = (descriptor, 1)
    try:
        yield
    finally:
        del _held[key]
        os.close(descriptor)  # closing the only descriptor releases the flock


def _in_use_message(run_dir: Path, holder_text: str) -> str:
    try:
        holder = json.loads(holder_text)
        who = f"pid {holder['pid']} on {holder['host']}, started {holder['started']}"
    except (ValueError, KeyError, TypeError):
        who = "a process that has not yet named itself"
    return (f"{run_dir} is in use by another run ({who}): one process writes a run folder at a time. Wait for it "
            "to end (or stop it: it checkpoints on SIGTERM or Ctrl-C), or choose another folder (hydra.run.dir=...)")


def temporary_name(path: Path) -> Path:
    """The temporary file beside ``path`` that this process writes before its atomic rename: named by host and pid,
    so two writers never share one (and a leftover names the process that left it)."""
    return path.with_name(f".{path.name}.{socket.gethostname()}.{os.getpid()}.tmp")


def atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    """Write ``path`` through a temporary file beside it and an atomic rename: readers see old or new, never half."""
    tmp = temporary_name(path)
    write(tmp)
    os.replace(tmp, path)


# ---- reading files back -----------------------------------------------------------------------------------------


def read_torch_file(path: str | Path, map_location: Any = "cpu", mmap: bool = False) -> Any:
    """The one way the package reads a ``.pt`` file back (``policy.pt``, ``checkpoint.pt``, ``checkpoint.prev.pt``):
    ``torch.load(weights_only=True)`` with only the safe types of ``sidewalk._torchrl.checkpoint_safe_globals`` allowed.

    Raises ``UnsafeFile`` naming the file and the types it holds when it holds anything else (nothing in it is
    built or run), and ``UnreadableFile`` when it is torn, corrupt or not a torch file.
    """
    import torch

    from sidewalk._torchrl import checkpoint_safe_globals  # torchrl's import only where a file is read

    path = Path(path)
    try:
        with torch.serialization.safe_globals(checkpoint_safe_globals()):
            return torch.load(path, map_location=map_location, weights_only=True, mmap=mmap)
    except pickle.UnpicklingError as error:
        try:
            allowed = {item[1] if isinstance(item, tuple) else f"{item.__module__}.{item.__qualname__}"
                       for item in checkpoint_safe_globals()}
            held = [name for name in torch.serialization.get_unsafe_globals_in_checkpoint(path) if name not in allowed]
        except Exception:  # noqa: BLE001 (a file too broken to list is refused all the same)
            held = []
        if held:
            raise UnsafeFile(path, sorted(held)) from None
        raise UnreadableFile(path, f"UnpicklingError: {error}") from None
    except Exception as error:  # noqa: BLE001 (a torn or corrupt file raises whatever the reader meets)
        raise UnreadableFile(path, f"{type(error).__name__}: {error}") from None


def policy_file(run_dir: str | Path) -> Path | None:
    """Where a run's learned networks are: ``policy.pt`` (every run since it was added), else ``checkpoint.pt``
    (an unfinished run, or one written before), else None."""
    for name in (POLICY, CHECKPOINT):
        if (Path(run_dir) / name).exists():
            return Path(run_dir) / name
    return None


def read_saved_config(run_dir: str | Path) -> Any:
    """A run folder's ``config.yaml`` with every key it lacks filled from today's schemas (``with_schema_defaults``);
    raises ``FileNotFoundError`` when the folder has none, ``GroupFolderGiven`` naming a group folder's seeds'."""
    from sidewalk.schema import with_schema_defaults

    path = one_run_folder(run_dir) / CONFIG
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist: {run_dir} is not a run folder")
    return with_schema_defaults(OmegaConf.load(path))


def package_versions() -> dict[str, str]:
    """The versions of Python and of the packages a run's numbers depend on, for its ``summary.json``."""
    import platform

    import tensordict
    import torch
    import torchrl

    from sidewalk.version import __version__

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "torchrl": torchrl.__version__,
        "tensordict": tensordict.__version__,
        "sidewalk": __version__,
    }


def git_revision(root: Path | None = None) -> str:
    """The commit of the source tree (this package's, or ``root``), with ``-dirty`` when it has changes, or
    ``unknown`` outside git."""
    root = Path(__file__).resolve().parents[1] if root is None else Path(root)
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True, text=True, check=True)
        return rev.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


# ---- config and history ------------------------------------------------------------------------------------------


def flatten(config: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings to dotted keys (an empty one stays a value); lists become tuples so that values can be
    compared and hashed."""
    flat: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = tuple(value) if isinstance(value, list) else value
    return flat


def config_changes(old: Mapping[str, Any], new: Mapping[str, Any]) -> dict[str, tuple[Any, Any]]:
    """Every dotted key whose value differs between two resolved configs: ``{key: (old, new)}`` (absent: None)."""
    flat_old, flat_new = flatten(old), flatten(new)
    missing = object()
    changes = {}
    for key in sorted(set(flat_old) | set(flat_new)):
        before, after = flat_old.get(key, missing), flat_new.get(key, missing)
        if before != after:
            changes[key] = (None if before is missing else before, None if after is missing else after)
    return changes


def append_history(run_dir: Path, event: str, **details: Any) -> None:
    """Add one line to ``history.jsonl`` (appended and flushed: earlier lines are never rewritten)."""
    line = {"event": event, "time": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "git_revision": git_revision(), **details}
    with open(run_dir / HISTORY, "a") as file:
        file.write(json.dumps(line, default=str) + "\n")
        file.flush()
        os.fsync(file.fileno())


def check(run_dir: Path, config: dict[str, Any], resume: bool) -> tuple[int, int] | None:
    """Check that ``run_dir`` can start (or continue) the run of ``config``, before any compute; write nothing.

    A new run refuses a folder that already holds one. A resume refuses a folder that holds no run, a config that
    differs from the folder's in anything but a larger ``iterations`` (naming every differing key), and a larger
    ``iterations`` without a checkpoint to extend. A resume of a run stopped before its first checkpoint passes: it
    trains again from the start (``has_checkpoint``). Returns the budget's growth ``(old, new)`` of a resume that
    extends the run, else None.
    """
    saved = run_dir / CONFIG
    if not resume:
        if any((run_dir / name).exists() for name in (METRICS, CHECKPOINT, PREVIOUS_CHECKPOINT, SUMMARY)):
            raise RunFolderError(
                f"{run_dir} already holds a run; continue it with resume=true (same config) or choose a new folder "
                "(hydra.run.dir=...)"
            )
        return None
    if not saved.exists():
        raise RunFolderError(f"resume=true but {saved} does not exist: {run_dir} is not a run folder")
    from sidewalk.schema import with_schema_defaults  # the schemas import the learners: only when resuming

    # Keys added to the code since the folder was written compare at their defaults (the behaviour it ran with), on
    # both sides: a config made from the folder's own config.yaml lacks them too.
    old, new = (OmegaConf.to_container(with_schema_defaults(OmegaConf.create(c)), resolve=True)
                for c in (OmegaConf.load(saved), config))
    changes = {k: v for k, v in config_changes(old, new).items() if k not in RESUME_MAY_CHANGE}
    grown = changes.pop("iterations", None)
    if grown is not None and not (isinstance(grown[0], int) and isinstance(grown[1], int) and grown[1] > grown[0]):
        changes["iterations"] = grown  # only a larger budget continues the same experiment
        grown = None
    if changes:
        listed = "; ".join(f"{key}: {before!r} -> {after!r}" for key, (before, after) in changes.items())
        raise RunFolderError(
            f"resume=true with a config that differs from {saved} in {len(changes)} key(s): {listed}. A resumed run "
            "must be the same experiment (only a larger iterations may change); start a new folder for a new one"
        )
    if grown is not None and not has_checkpoint(run_dir):
        raise RunFolderError(f"resume=true but {run_dir} has no checkpoint to extend.{_finished_hint(run_dir)}")
    return grown


def has_checkpoint(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a checkpoint generation to resume from (readable or not: ``load_checkpoint`` says)."""
    return any((Path(run_dir) / name).exists() for name in (CHECKPOINT, PREVIOUS_CHECKPOINT))


def record_start(run_dir: Path, config: dict[str, Any], resume: bool) -> None:
    """Write ``config.yaml`` (new run, or a resume that grows ``iterations``) and the start to ``history.jsonl``;
    called once the run's state is loaded, so a resume that fails leaves the folder as it was."""
    grown = check(run_dir, config, resume)
    if not resume or grown is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write(run_dir / CONFIG, lambda tmp: OmegaConf.save(OmegaConf.create(config), tmp))
    if not resume:
        append_history(run_dir, "started", iterations=config.get("iterations"))
    elif not has_checkpoint(run_dir):
        append_history(run_dir, "restarted", iterations=config.get("iterations"), reason="no checkpoint yet")
    elif grown is not None:
        append_history(run_dir, "resumed", iterations={"from": grown[0], "to": grown[1]})
    else:
        append_history(run_dir, "resumed", iterations=config.get("iterations"))


def _finished_hint(run_dir: Path) -> str:
    if (run_dir / SUMMARY).exists() and (run_dir / POLICY).exists():
        return (" The run finished with keep_checkpoint=final, which keeps only policy.pt: to extend a run, train it "
                "with keep_checkpoint=all.")
    return ""


# ---- checkpoints -------------------------------------------------------------------------------------------------


def save_checkpoint(run_dir: Path, state: dict[str, Any]) -> None:
    """Write ``checkpoint.pt``, keeping the one it replaces as ``checkpoint.prev.pt``.

    The new file is complete on disk before either rename, so a kill at any point leaves at least one whole
    checkpoint (between the renames: only the previous one, which ``load_checkpoint`` then uses).
    """
    import torch  # here, so that the report (which reads only the names above) does not load torch

    current, previous = run_dir / CHECKPOINT, run_dir / PREVIOUS_CHECKPOINT
    tmp = temporary_name(current)
    with open(tmp, "wb") as file:
        torch.save(state, file)
        file.flush()
        os.fsync(file.fileno())
    if current.exists():
        os.replace(current, previous)
    os.replace(tmp, current)


def load_checkpoint(run_dir: Path, map_location: Any = "cpu") -> dict[str, Any]:
    """The newest readable checkpoint of ``run_dir``: ``checkpoint.pt``, or, when that is missing, truncated or
    corrupt, ``checkpoint.prev.pt`` (with a warning naming the bad file and the error). A checkpoint that holds
    more than a checkpoint does (``UnsafeFile``) is refused outright: it is no torn write, and none of it runs.
    Raises ``RunFolderError`` saying what to do when neither reads back."""
    name, state, unreadable = _newest_readable(run_dir, lambda path: read_torch_file(path, map_location), warn=True)
    if unreadable:
        append_history(run_dir, "checkpoint_fallback", unreadable=unreadable, used=name)
    return state


def check_checkpoint(run_dir: Path) -> None:
    """Before any compute: raise ``load_checkpoint``'s ``RunFolderError`` unless one checkpoint generation of
    ``run_dir`` reads back. Cheap (the tensors are mapped, not read) and silent (a fallback warns when it loads)."""
    _newest_readable(run_dir, _map_torch_file, warn=False)


def _map_torch_file(path: Path) -> Any:
    try:
        return read_torch_file(path, mmap=True)
    except UnsafeFile:
        raise
    except UnreadableFile:
        return read_torch_file(path)  # mmap maps only the zip format: an older file may still read, or says why not


def _newest_readable(
    run_dir: Path, read: Callable[[Path], Any], warn: bool
) -> tuple[str, Any, list[str]]:
    """The first generation that ``read`` reads back, what it read, and the generations before it that it could
    not; ``RunFolderError`` (one line: why, and what to do) when none reads."""
    present = [name for name in (CHECKPOINT, PREVIOUS_CHECKPOINT) if (run_dir / name).exists()]
    reasons: dict[str, str] = {}
    for index, name in enumerate(present):
        try:
            return name, read(run_dir / name), [f"{bad}: unreadable ({reason})" for bad, reason in reasons.items()]
        except UnsafeFile:
            raise
        except UnreadableFile as error:
            reasons[name] = _first_sentence(error.detail)  # torch's miniz text runs on for three sentences
        if warn and index + 1 < len(present):
            print(f"warning: {run_dir / name} is unreadable ({reasons[name]}); trying the previous checkpoint, "
                  f"{present[index + 1]}", file=sys.stderr)
    raise RunFolderError(_no_readable_checkpoint(run_dir, reasons))


def _first_sentence(text: str) -> str:
    lines = text.strip().splitlines()
    return lines[0].split(". ", 1)[0].rstrip(".") if lines else text


def _no_readable_checkpoint(run_dir: Path, reasons: dict[str, str]) -> str:
    """Why ``run_dir`` cannot resume, and the two ways on: train again from the start there, or in a new folder."""
    import shlex

    if not reasons:
        return f"resume=true but {run_dir} holds no checkpoint.{_finished_hint(run_dir)}"
    if len(reasons) > 1 and len(set(reasons.values())) == 1:
        why = f"{' and '.join(reasons)} are unreadable ({next(iter(reasons.values()))})"
    else:
        why = ", ".join(f"{name} is unreadable ({reasons[name]})" if name in reasons else f"{name} is missing"
                        for name in (CHECKPOINT, PREVIOUS_CHECKPOINT))
    remove = shlex.join(["rm", *(str(run_dir / name) for name in reasons)])
    return (f"resume=true but {run_dir} has no readable checkpoint: {why}. To train the run again from the start in "
            f"this folder, delete its checkpoints ({remove}) and run the same command again; or start afresh in a new "
            "folder: the same command with hydra.run.dir=<a new folder> and without resume=true")


def strict_json(value: Any) -> Any:
    """``value`` with every non-finite float (an undefined metric: no agent arrived, so no path efficiency) made
    null, in nested dicts too: strict JSON has no NaN."""
    if isinstance(value, dict):
        return {key: strict_json(item) for key, item in value.items()}
    return None if isinstance(value, float) and not math.isfinite(value) else value


def save_policy(run_dir: Path, modules_state: dict[str, Any], name: str = POLICY) -> None:
    """Write ``policy.pt`` (or ``name``): the learner's networks (``Algorithm.modules()`` state) and what they learned
    on, small enough to keep."""
    import torch

    atomic_write(run_dir / name, lambda tmp: torch.save(modules_state, tmp))


def drop_training_state(run_dir: Path) -> None:
    """Remove both checkpoint generations (after ``policy.pt`` and ``summary.json`` are written)."""
    for name in (CHECKPOINT, PREVIOUS_CHECKPOINT):
        (run_dir / name).unlink(missing_ok=True)


def policy_description(algo: Any, world: World) -> dict[str, Any]:
    """The part of ``policy.pt`` that says what its networks are: the learner, its settings, and the World they
    learned in (plain data, read back by ``saved_world``), all a replay or a learned partner needs."""
    import dataclasses

    return {"algo_name": algo.name, "algo": dataclasses.asdict(algo), "world": world.to_dict()}


def saved_world(description: Mapping[str, Any] | None, run_dir: str | Path) -> tuple[str, dict[str, Any], World]:
    """The learner's name and settings and the World of a ``policy.pt`` ``description``. Older files are read too:
    one that named its world's domain, env parameters, opponent and ego (before the World), and one written before
    ``policy.pt`` described anything (None: the run folder's ``config.yaml`` says)."""
    import dataclasses

    from sidewalk.schema import env_params_of
    from sidewalk.world import World, env_params_from_dict

    if description is None:
        cfg = read_saved_config(run_dir)
        description = {"algo_name": cfg.algo.name, "algo": dataclasses.asdict(OmegaConf.to_object(cfg.algo)),
                       "domain": cfg.env.domain, "env_params": dataclasses.asdict(env_params_of(cfg)),
                       "opponent": cfg.opponent.name, "ego": cfg.opponent.ego}
    if "world" in description:
        world = World.from_dict(description["world"])
    else:
        domain = description["domain"]
        world = World(domain, env_params_from_dict(domain, description["env_params"]), description["opponent"],
                      ego=int(description["ego"] or 0))
    return description["algo_name"], dict(description["algo"]), world
