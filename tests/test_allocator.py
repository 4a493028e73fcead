"""nitsche.allocator: freed blocks stay in the heap, so touching a new one costs no page faults."""
import os
import subprocess
import sys

import pytest

TOUCH = """
import contextlib, ctypes, resource, sys
import nitsche
from nitsche.allocator import freed_memory_returned, keep_freed_memory
if sys.argv[1:2] == ["keep"]:
    keep_freed_memory()
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
n = 64 << 20

def freed():
    a = libc.malloc(n); ctypes.memset(a, 1, n); libc.free(a)    # a large block, freed
if sys.argv[2:] == ["thread"]:  # ... by another thread (the finest level built ahead)
    import threading
    t = threading.Thread(target=freed); t.start(); t.join()
else:
    freed()

def touched():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = libc.malloc(n); ctypes.memset(b, 1, n); libc.free(b)    # the next one, touched
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
if sys.argv[2:] == ["returned"]:  # within freed_memory_returned, then after it
    with freed_memory_returned():
        freed()
        print(touched())
    freed()
print(touched())
"""


def faults(keep=True, thread=False, returned=False, **env):
    """Minor page faults of touching a 64 MB block after freeing one (thread: freed by
    another thread), in a fresh process that imports nitsche and (keep) calls
    keep_freed_memory as the `nitsche` command does; returned: [within
    freed_memory_returned, after it]."""
    environ = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    mode = ["thread"] if thread else ["returned"] if returned else []
    out = subprocess.run([sys.executable, "-c", TOUCH, "keep" if keep else "-"] + mode,
                         env=dict(environ, **env), capture_output=True,
                         text=True, check=True)
    counts = [int(c) for c in out.stdout.split()]
    return counts if returned else counts[-1]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_freed_large_block_is_reused_without_page_faults():
    import ctypes
    try:
        ctypes.CDLL(None).mallopt
    except AttributeError:
        pytest.skip("no mallopt in this C library")
    pages = (64 << 20) // 4096
    kept, system = faults(), faults(NITSCHE_MALLOC="system")
    assert kept < 0.05 * pages, kept          # the freed block's pages, already resident
    assert system > 0.5 * pages, system       # unmapped on free: every page faulted anew
    assert faults(MALLOC_MMAP_MAX_="65536") > 0.5 * pages  # a user's tunable is left alone
    assert faults(keep=False) > 0.5 * pages   # importing the library leaves malloc alone
    assert faults(thread=True) < 0.05 * pages  # one arena: another thread's freed block too


def test_opting_out_leaves_malloc_alone(monkeypatch):
    from nitsche.allocator import keep_freed_memory
    monkeypatch.setenv("NITSCHE_MALLOC", "system")
    assert keep_freed_memory() is False
    monkeypatch.delenv("NITSCHE_MALLOC")
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "131072")
    assert keep_freed_memory() is False


RELEASE = """
import ctypes
import nitsche
from nitsche.allocator import keep_freed_memory, release_freed_memory
keep_freed_memory()
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
def rss():
    with open("/proc/self/status") as fh:
        return next(int(l.split()[1]) for l in fh if l.startswith("VmRSS")) * 1024
n = 64 << 20
keep = libc.malloc(1 << 20); ctypes.memset(keep, 1, 1 << 20)
a = libc.malloc(n); ctypes.memset(a, 1, n)
guard = libc.malloc(1 << 20); ctypes.memset(guard, 1, 1 << 20)  # above it: no trim from the top
libc.free(a)
before = rss(); released = release_freed_memory(); print(released, before - rss())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_release_gives_a_kept_free_block_back():
    environ = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    out = subprocess.run([sys.executable, "-c", RELEASE], env=environ, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[0] == "True" and int(out[1]) > 0.9 * (64 << 20)  # the freed block's pages



@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_within_freed_memory_returned_a_freed_block_goes_back_and_after_it_is_kept_again():
    pages = (64 << 20) // 4096
    inside, after = faults(returned=True)
    assert inside > 0.5 * pages, inside   # unmapped when freed: every page faulted anew
    assert after < 0.05 * pages, after    # kept for the next one again
    assert faults(keep=False, returned=True)[1] > 0.5 * pages  # the library alone: malloc's own
