"""An output folder written as one transaction: a run's files appear together or not at all.

    with OutputFolder(path) as out:            # checks the folder, locks it, stages
        write_json(out.stage("result.json"), data)
        out.commit()                           # renamed into place, result.json last

Before anything is staged the folder must be writable, not locked by another run,
and hold no nitsche outputs that no manifest records (an earlier version's run)
unless `overwrite`.  Files are written into a hidden staging folder inside it; commit
renames them into place with SIGINT and SIGTERM held (delivered after it), result.json last (its presence
means the run is whole), removes what the previous run's manifest lists and this run
did not write, and writes the new manifest.  Without a commit (an error, a signal, a
full disk) the staging folder is removed and the folder holds what it held before.
"""
import contextlib
import errno
import fcntl
import json
import os
import shutil
import signal
import sys
import threading

MANIFEST = ".nitsche-manifest.json"
LOCK = ".nitsche.lock"
STAGING = ".nitsche-staging-"
OUTPUT_SUFFIXES = (".vtu", ".pvtu", ".pvd", ".png")       # what nitsche writes ...
OUTPUT_NAMES = ("result.json", "study.json", "log.txt", "index.md")  # ... besides these
LAST = ("result.json", "study.json", "index.md")          # renamed in after the rest
HELD = (signal.SIGINT, signal.SIGTERM)


class OutputError(ValueError):
    """The output folder cannot be used (a file, not writable, locked, foreign outputs)."""


class Interrupted(BaseException):
    """SIGTERM (or SIGINT) received: the run stops, its staged files are removed."""

    def __init__(self, signum):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def raise_interrupted(signum, frame):
    """Signal handler: turn SIGTERM into an exception, so that clean-up code runs."""
    raise Interrupted(signum)


_IGNORED = []  # an interruption Python ignored, to be raised again


def redeliver_ignored(unraisable):
    """sys.unraisablehook: an interruption raised where Python ignores exceptions (the
    handler ran inside a garbage-collector callback or a __del__) is raised again a
    millisecond later by a SIGALRM handler, in the main thread's ordinary code (again,
    should that land in such a callback too)."""
    e = unraisable.exc_value
    if isinstance(e, (Interrupted, KeyboardInterrupt)):
        _IGNORED[:] = [e]
        signal.signal(signal.SIGALRM, _raise_ignored)
        signal.setitimer(signal.ITIMER_REAL, 1e-3)
    else:
        sys.__unraisablehook__(unraisable)


def _raise_ignored(signum, frame):
    raise _IGNORED.pop()


@contextlib.contextmanager
def held_signals():
    """SIGINT and SIGTERM received inside the block are delivered when it ends (Python runs
    signal handlers in the main thread; elsewhere nothing is held)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending = []
    previous = {s: signal.signal(s, lambda signum, frame: pending.append(signum)) for s in HELD}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for s in pending[:1]:
            signal.raise_signal(s)


def is_output(name):
    return name.endswith(OUTPUT_SUFFIXES) or name in OUTPUT_NAMES


def _first_existing(path):
    path = os.path.abspath(path)
    while not os.path.exists(path):
        path = os.path.dirname(path)
    return path


def check_folder(path, option="--out"):
    """Raise OutputError unless `path` is, or can be created as, a folder we can write."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise OutputError(f"{option} {path} is a file, not a folder; choose a folder name")
    base = _first_existing(path)
    if not os.path.isdir(base):
        raise OutputError(f"{option} {path}: {base} is a file, so the folder cannot be created; "
                          "choose another path")
    if not os.access(base, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {path}: {base} is not writable; choose a folder you can write")


class OutputFolder:
    """The files of one run into `path`, committed together (see the module docstring)."""

    def __init__(self, path, overwrite=False, option="--out"):
        check_folder(path, option)
        self.path, self.overwrite, self.option = path, overwrite, option
        self.staged, self._lock, self._created = [], None, []
        self.staging, self.committed = None, False

    def __enter__(self):
        self._created = self._make_folders()
        try:
            self._acquire()
            self._previous = self._read_manifest()
            if self._previous is None:
                foreign = sorted(f for f in os.listdir(self.path) if is_output(f))
                if foreign and not self.overwrite:
                    shown = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
                    raise OutputError(
                        f"{self.option} {self.path} holds outputs of an unknown earlier run "
                        f"({shown}); choose a new or empty folder, or pass --overwrite to "
                        "replace them")
                self._previous = foreign
            for stale in os.listdir(self.path):  # left by a killed run (we hold the lock)
                if stale.startswith(STAGING):
                    shutil.rmtree(os.path.join(self.path, stale), ignore_errors=True)
            self.staging = os.path.join(self.path, f"{STAGING}{os.getpid()}")
            os.mkdir(self.staging)
        except BaseException:
            self._abandon()
            raise
        return self

    def __exit__(self, *exc):
        self._abandon()
        return False

    def _make_folders(self):
        """Create the folder (and missing parents); return those created, deepest first."""
        created, p = [], os.path.abspath(self.path)
        while not os.path.exists(p):
            created.append(p)
            p = os.path.dirname(p)
        try:
            os.makedirs(self.path, exist_ok=True)
        except OSError as e:
            raise OutputError(f"{self.option} {self.path}: cannot create the folder "
                              f"({e.strerror}); choose another path")
        return created

    def _acquire(self):
        try:
            fd = os.open(os.path.join(self.path, LOCK), os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise OutputError(f"{self.option} {self.path}: cannot write into the folder "
                              f"({e.strerror}); choose a folder you can write")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            owner = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise OutputError(f"{self.option} {self.path}: another nitsche run (pid {owner}) "
                                  "is writing into this folder; wait for it or choose another")
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._lock = fd

    def _read_manifest(self):
        try:
            with open(os.path.join(self.path, MANIFEST)) as fh:
                return [f for f in json.load(fh)["files"] if os.path.basename(f) == f]
        except FileNotFoundError:
            return None
        except (ValueError, KeyError, TypeError):  # a damaged manifest: treat as unknown
            return None

    def stage(self, name):
        """The path to write the output file `name` to (inside the staging folder)."""
        if os.path.basename(name) != name or name.startswith("."):
            raise ValueError(f"output file names are plain names, not {name!r}")
        if name not in self.staged:
            self.staged.append(name)
        return os.path.join(self.staging, name)

    def stage_prefix(self, prefix):
        """A path prefix in the staging folder, for writers that add their own suffixes
        (register what they wrote with adopt)."""
        return os.path.join(self.staging, prefix)

    def adopt(self, paths):
        """Register files written directly into the staging folder (e.g. by a case's
        figure hook); returns their names."""
        names = []
        for path in paths:
            if os.path.dirname(os.path.abspath(path)) != os.path.abspath(self.staging):
                raise ValueError(f"{path} was not written into the staging folder")
            names.append(os.path.basename(path))
            if names[-1] not in self.staged:
                self.staged.append(names[-1])
        return names

    def write_text(self, name, text):
        with open(self.stage(name), "w") as fh:
            fh.write(text)

    def commit(self):
        """Rename the staged files into place (SIGINT/SIGTERM held): the rest first, then
        result.json / study.json; remove the previous run's files that this one did not write."""
        missing = [n for n in self.staged if not os.path.exists(os.path.join(self.staging, n))]
        if missing:
            raise OSError(f"staged output files were not written: {missing}")
        names = sorted(self.staged, key=lambda n: n in LAST)
        manifest = os.path.join(self.staging, MANIFEST)  # written before anything changes
        with open(manifest, "w") as fh:
            json.dump({"files": names}, fh)
        with held_signals():  # from here on only removals and renames
            for n in LAST:  # the old run is no longer whole from here on
                if n in self._previous and os.path.exists(os.path.join(self.path, n)):
                    os.remove(os.path.join(self.path, n))
            for n in self._previous:
                if n not in names and os.path.exists(os.path.join(self.path, n)):
                    os.remove(os.path.join(self.path, n))
            os.replace(manifest, os.path.join(self.path, MANIFEST))
            for n in names:
                os.replace(os.path.join(self.staging, n), os.path.join(self.path, n))
            self._created, self.committed = [], True
        return [os.path.join(self.path, n) for n in names]

    def _abandon(self):
        """Remove the staging folder, release the lock, remove folders this run created
        if nothing was committed into them."""
        if self.staging:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None
        for folder in self._created:
            try:
                os.remove(os.path.join(folder, LOCK))
            except OSError:
                pass
            try:
                os.rmdir(folder)
            except OSError:
                break
        self._created = []
