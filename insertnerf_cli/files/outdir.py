"""Output locations: where a command may write, and what `--overwrite` may remove.

Every output folder keeps a record, ``.insertnerf-outputs.json``, of the paths (relative to it) that insertnerf
created there. A path is recorded *before* it is created, so a killed run leaves nothing of ours unrecorded, and
``--overwrite`` removes recorded paths only: a user's file beside ours, or inside one of our folders, survives
(a recorded folder is removed only once it is empty). A recorded folder may hold a record of its own (a synth
scene, a posed scene); removal then follows that record too. Folders written by versions without records are
cleared by the exact file-name patterns those versions wrote, never wholesale.

The location checks run before any work: an output that is, holds or lies inside an input is refused (resolved
paths, symlinks followed), and so is one whose parent is a file or not writable. The package's bundled weights
folder is an input of every command.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterable, Sequence

from insertnerf_cli.errors import UserError
from insertnerf_cli.files.atomic import stray_temporaries, write_json
from insertnerf_cli.files.lock import is_lock_name

RECORD_NAME = ".insertnerf-outputs.json"
# The pretrained weights shipped in the package (checkpoint.bundled_checkpoint): an input of every command, never
# an output, whatever a user passes (`finetune --out <site-packages>/insertnerf_cli/weights/insertnerf.pt`).
BUNDLED_WEIGHTS_DIR = Path(__file__).resolve().parents[1] / "weights"
_RECORD_KIND = "insertnerf outputs"


# ------------------------------------------------------------------------------------------------ locations
def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(path)).resolve()  # resolve(strict=False) follows every existing symlink


def check_not_inside_inputs(out: Path, inputs: Iterable[Path | None], what: str = "--out",
                            kind: str = "input") -> None:
    """Refuse an output that is, contains, or lies inside one of ``inputs`` (None entries are skipped);
    ``kind`` names the inputs in the message ("input images")."""
    target = _resolved(out)
    for given in inputs:
        if given is None:
            continue
        source = _resolved(given)
        if target == source or source in target.parents:
            where = "is" if target == source else "lies inside"
            raise UserError(f"{what} {out} {where} the {kind} {given}; insertnerf never writes into its inputs: "
                            "choose an output outside it.")
        if target in source.parents:
            raise UserError(f"{what} {out} contains the {kind} {given}; choose an output folder that does not "
                            "hold your input data (replacing it could delete them).")


def _nearest_existing(path: Path) -> Path:
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_writable(path: Path, is_dir: bool, what: str = "--out") -> None:
    """Refuse, before any work, an output path that cannot be created or written.

    ``path`` is an output folder (``is_dir``) or file. Its nearest existing ancestor must be a writable folder; a
    file in the way, or a folder of the wrong kind at ``path``, is refused.
    """
    if path.exists():
        if is_dir and not path.is_dir():
            raise UserError(f"{what} {path} is a file; pass a folder.")
        if not is_dir and path.is_dir():
            raise UserError(f"{what} {path} is a folder; pass a file name.")
        folder = path if is_dir else path.parent
    else:
        folder = _nearest_existing(path.parent)
        if not folder.is_dir():
            raise UserError(f"{what} {path} cannot be created: {folder} is a file, not a folder; choose another "
                            "path.")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UserError(f"{what} {path}: no permission to write in {folder}; choose a folder you can write to, "
                        "or change its permissions.")


def check_output(out: Path, inputs: Sequence[Path | None], is_dir: bool = True, what: str = "--out",
                 kind: str = "input") -> None:
    """Both checks above: the output is away from the inputs and from the bundled weights, and can be written."""
    check_not_inside_inputs(out, inputs, what, kind)
    check_not_inside_inputs(out, [BUNDLED_WEIGHTS_DIR], what, kind="package's bundled weights folder")
    check_writable(out, is_dir, what)


# --------------------------------------------------------------------------------------------------- record
def _clean_name(name: str) -> str | None:
    """A record entry as a relative POSIX path inside its folder, or None for one that would leave it."""
    if not isinstance(name, str) or not name or name.startswith("/") or "\\" in name:
        return None
    parts = [p for p in name.split("/") if p not in ("", ".")]
    if not parts or ".." in parts:
        return None
    return "/".join(parts)


class OutputRecord:
    """What command ``owner`` ("render", "train", ...) created in the output folder ``root``, relative to it.

    The record file keeps one list per command, so `render --overwrite` into a training run's folder leaves the
    run's checkpoints alone: each command removes only its own outputs.
    """

    def __init__(self, root: Path, owner: str) -> None:
        self.root, self.owner = Path(root), owner
        self.file = self.root / RECORD_NAME
        self._all = self._read()
        self.paths: set[str] = set(self._all.get(owner, set()))
        self.exists = owner in self._all  # False: outputs of a version before records may be there

    def _read(self) -> dict[str, set[str]]:
        try:
            data = json.loads(self.file.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}  # none yet, or unreadable: an unreadable record removes nothing and is rewritten
        owners = data.get("owners", {}) if isinstance(data, dict) else {}
        return {str(owner): {n for n in map(_clean_name, names) if n}
                for owner, names in (owners.items() if isinstance(owners, dict) else []) if isinstance(names, list)}

    def _write(self) -> None:
        self._all[self.owner] = set(self.paths)
        self._all = {owner: names for owner, names in self._all.items() if names}
        self.exists = self.owner in self._all
        if not self._all:
            self.file.unlink(missing_ok=True)
            return
        write_json(self.file, {"kind": _RECORD_KIND,
                               "owners": {owner: sorted(names) for owner, names in sorted(self._all.items())}})

    def owners(self) -> list[str]:
        """The commands with outputs recorded in this folder."""
        return sorted(self._all)

    def claim(self, *names: str) -> None:
        """Record ``names`` (relative to root, folders too) before creating them; creates root if needed."""
        new = {n for n in map(_clean_name, names) if n} - self.paths
        if new or not self.exists:
            self.root.mkdir(parents=True, exist_ok=True)
            self.paths |= new
            self._write()

    def remove(self, legacy: Sequence[str] = (), keep: Sequence[str] = ()) -> None:
        """Delete this command's recorded paths (or, with no record of it, those matching the ``legacy`` glob
        patterns; a pattern ending in "/" names folders), except those under a top-level name in ``keep``;
        other files, and other commands' outputs, stay."""
        names = self.paths if self.exists else {n for p in legacy for n in self._glob(p)}
        names -= {n for other, theirs in self._all.items() if other != self.owner for n in theirs}
        kept = {n for n in names if n.split("/")[0] in keep}
        root = _resolved(self.root)
        for name in sorted(names - kept, key=lambda n: (-n.count("/"), n)):  # children before their folders
            parent = _resolved((self.root / name).parent)
            if parent == root or root in parent.parents:  # never through a symlink that leads elsewhere
                _remove_one(self.root / name)
        self.paths = {n for n in self.paths if n in kept or os.path.lexists(self.root / n)}
        if self.root.is_dir():
            self._write()

    def _glob(self, pattern: str) -> list[str]:
        matches = self.root.glob(pattern.rstrip("/"))
        return [p.relative_to(self.root).as_posix() for p in matches if pattern.endswith("/") == p.is_dir()]


def _remove_one(path: Path) -> None:
    """Remove one recorded path: a file (and stray temporaries of it), or a folder once it is empty (after its
    own record's contents, when it has one)."""
    if path.is_symlink() or path.is_file():
        path.unlink(missing_ok=True)
    elif path.is_dir():
        for owner in OutputRecord(path, "").owners():
            OutputRecord(path, owner).remove()
        remove_if_empty(path)
    for temp in stray_temporaries(path):
        temp.unlink(missing_ok=True)


def record_name(root: Path, path: Path) -> str:
    """``path`` (inside ``root``) as a record names it: relative to root, with forward slashes."""
    return Path(path).relative_to(root).as_posix()


def remove_if_empty(folder: Path) -> None:
    """Remove ``folder`` if nothing is left in it (a user's file inside keeps it)."""
    try:
        folder.rmdir()
    except OSError:
        pass


def record_tree(folder: Path, owner: str) -> None:
    """Record every file and folder now under ``folder`` in its own record (for a folder built whole in a
    temporary place and renamed into the output)."""
    names = [p.relative_to(folder).as_posix() for p in folder.rglob("*")
             if p.name != RECORD_NAME and not is_lock_name(p.name)]
    OutputRecord(folder, owner).claim(*names)


def move_into(source: Path, target: Path, owner: str) -> None:
    """Make the folder ``source`` (built elsewhere, with its own record) the output ``target``: a rename when
    ``target`` is new or empty, else its entries move in one by one and its record joins target's. Files at the
    same names are replaced; anything else in ``target`` stays."""
    if not target.exists() or (target.is_dir() and not any(target.iterdir())):
        os.replace(source, target)
        return
    OutputRecord(target, owner).claim(*OutputRecord(source, owner).paths)
    for entry in sorted(source.iterdir()):
        if entry.name != RECORD_NAME:
            _merge(entry, target / entry.name)


def _merge(source: Path, target: Path) -> None:
    """Move ``source`` to ``target``, into an existing folder entry by entry."""
    if target.is_dir() and not target.is_symlink() and source.is_dir():
        for child in sorted(source.iterdir()):
            _merge(child, target / child.name)
    elif target.is_dir():
        raise UserError(f"cannot write {target}: a folder that is not insertnerf's is in the way; move it away "
                        "and re-run.")
    else:
        os.replace(source, target)


def foreign_entries(root: Path, owner: str) -> list[str]:
    """Top-level names in ``root`` that ``owner``'s record does not list (empty for a missing folder)."""
    if not root.is_dir():
        return []
    ours = {n.split("/")[0] for n in OutputRecord(root, owner).paths}
    ours |= {t.name for n in ours for t in stray_temporaries(root / n)}
    return sorted(p.name for p in root.iterdir() if p.name != RECORD_NAME and p.name not in ours
                  and not is_lock_name(p.name))


def holds_files(folder: Path) -> bool:
    """Whether ``folder`` holds anything besides insertnerf's lock files (a killed run may leave one)."""
    return folder.is_dir() and any(not is_lock_name(p.name) for p in folder.iterdir())
