"""A run folder that ``jax-contact train --overwrite`` replaces, kept until it is replaced.

``--overwrite`` used to delete the earlier run when the new one started: a new run stopped
(Ctrl-C, an error) before its first checkpoint left neither. Now the earlier run is moved
aside to ``<run>.earlier`` (:func:`earlier_path`, a sibling, so the move is a rename on the
same file system) and:

- deleted once the new run has a checkpoint (:meth:`EarlierRun.settle`, called after each
  evaluation and when the training returns): from then on the new run is what
  ``policy-eval`` can load;
- moved back if the new run stops before that (:meth:`EarlierRun.restore`: on an error, and
  as the note of a Ctrl-C, :func:`jax_contact.train.interrupt.set_kept`).

A new run into a free folder that stops before its first checkpoint is removed
(:meth:`EarlierRun.remove_unsaved`): it holds nothing to evaluate.

A ``<run>.earlier`` left by a process that was killed outright (SIGKILL, power loss) is not
touched: :func:`jax_contact.train.cli_args.check_run_folder` refuses to train into
``<run>`` until the user has moved it back or deleted it.

Standard library only (the CLI checks run folders before JAX loads).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from jax_contact.train import interrupt

# What ``jax-contact train`` writes into a run folder (besides ``checkpoints/``) and into
# its --out folder: outputs of other commands must not replace them.
RUN_FILES = ("run.json", "progress.csv", "training.csv", "reward.png")
SUMMARY_FILES = ("summary.json", "reward_curves.csv", "training_curves.csv", "reward_curves.png")


def earlier_path(run_dir: Path) -> Path:
    """Where an ``--overwrite`` run keeps the run it replaces until its first checkpoint."""
    run_dir = Path(run_dir)
    return run_dir.with_name(run_dir.name + ".earlier")


# Brax's PPO checkpoint writes this file last, after orbax has moved the parameters in.
CHECKPOINT_CONFIG = "ppo_network_config.json"


def complete_checkpoints(run_dir: Path) -> list[Path]:
    """The checkpoint folders of ``run_dir`` that Brax finished saving, oldest first.

    Brax saves a checkpoint as ``checkpoints/<step>/``: it makes the folder, has orbax
    write the parameters (into a temporary folder renamed into place) and writes
    ``ppo_network_config.json`` last. A folder without that file as readable JSON is a
    save that was stopped (Ctrl-C, a full disk) and is not a checkpoint.
    """
    folder = Path(run_dir) / "checkpoints"
    if not folder.is_dir():
        return []
    done = []
    for p in folder.iterdir():
        if p.is_dir() and p.name.isdigit():
            try:
                json.loads((p / CHECKPOINT_CONFIG).read_text())
            except (OSError, ValueError):
                continue
            done.append(p)
    return sorted(done, key=lambda p: int(p.name))


def has_checkpoint(run_dir: Path) -> bool:
    """True if ``run_dir`` holds a checkpoint that Brax finished saving."""
    return bool(complete_checkpoints(run_dir))


class EarlierRun:
    """The earlier run of one run folder, set aside while a new run starts there.

    Args:
      run_dir: the run folder.
      replace: whether it holds an earlier run to replace
        (:func:`jax_contact.train.cli_args.check_run_folder`'s answer); if False, every
        method does nothing.
    """

    def __init__(self, run_dir: Path, replace: bool):
        self.run_dir = Path(run_dir)
        self.path = earlier_path(self.run_dir)
        self.kept = False  # the earlier run sits at self.path
        if replace:
            self.run_dir.rename(self.path)
            self.kept = True

    def settle(self) -> None:
        """Deletes the earlier run once the new run has a checkpoint."""
        if self.kept and has_checkpoint(self.run_dir):
            shutil.rmtree(self.path)
            self.kept = False

    def drop(self) -> None:
        """Deletes the earlier run (the new run has finished)."""
        if self.kept:
            shutil.rmtree(self.path)
            self.kept = False

    def restore(self) -> bool:
        """Puts the earlier run back in the run folder if the new run has no checkpoint (the
        new run's files are deleted); True if it did. With a checkpoint the new run stays
        and the earlier one is deleted (:meth:`settle`)."""
        self.settle()
        if not self.kept:
            return False
        shutil.rmtree(self.run_dir, ignore_errors=True)
        if self.run_dir.exists():  # a file still being written: leave both where they are
            return False
        self.path.rename(self.run_dir)
        self.kept = False
        interrupt.discarded(self.run_dir)  # the new run's files: not "written" any more
        return True

    def note(self) -> str | None:
        """What a stop at this point leaves, restoring the earlier run if it can (the
        callable given to :func:`jax_contact.train.interrupt.set_kept`)."""
        if self.restore():
            return (
                f"stopped before the first checkpoint: the earlier run is back in {self.run_dir}"
                " as it was"
            )
        if has_checkpoint(self.run_dir):
            return (
                f"kept {self.run_dir} (run.json: finished false) with the checkpoints saved so"
                f" far: `jax-contact policy-eval {self.run_dir}` evaluates the latest; train it"
                " again with --overwrite"
            )
        if self.kept:
            return (
                f"stopped before the first checkpoint: the earlier run is in {self.path}; move"
                f" it back to {self.run_dir} or delete it before training again"
            )
        if self.remove_unsaved():
            return (
                f"stopped before the first checkpoint: nothing of the run is kept"
                f" ({self.run_dir} removed; train again as before)"
            )
        return (
            f"kept {self.run_dir} (run.json: finished false) with no checkpoint yet: train it"
            " again with --overwrite"
        )

    def remove_unsaved(self) -> bool:
        """Removes the new run's folder if it holds no checkpoint and no earlier run is
        set aside; True if it did. Brax saves a checkpoint before each evaluation's
        report, so such a folder holds a ``run.json`` and no progress row: kept, it only
        made the next ``train`` into it ask for ``--overwrite`` (a helper's trial)."""
        if self.kept or has_checkpoint(self.run_dir) or not self.run_dir.is_dir():
            return False
        shutil.rmtree(self.run_dir, ignore_errors=True)
        if self.run_dir.exists():  # a file still being written: leave it
            return False
        interrupt.discarded(self.run_dir)  # its files: not "written" any more
        return True
