"""Work of one render or eval shared among processes side by side on a CPU (no click here).

On a CPU, whole frames in separate processes beat one frame's chunks on separate threads: a chunk makes about a
thousand small torch calls, and between them two threads take turns at Python's global lock. Two one-thread
processes scale to 1.95x one thread where two threads reach 1.6-1.7x; room's 30 frames took 0.76-0.94x the time
of one two-thread process, with the pixels of a one-thread render (docs/research-log.md, Speed). The items (a
render's frames, an eval's held-out views) are shared thus: this process works from the front of the list, while
spawned children take items from the back, so a child's start-up (importing torch and this package, a few
seconds) costs nothing but its own late start, and neighbouring items, which share their reference views'
encodings, stay on one process. An item a child claimed but never reported (the child failed or died) is done
here at the end. Children import the package afresh: a probe that patches the render path in this process must
pass workers=1 (RenderConfig.workers, EvalConfig.workers), or the children's items are done unpatched.
"""
from __future__ import annotations

import multiprocessing
import os
import queue
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Protocol

import torch

from insertnerf_cli.poses.child import become_child
from insertnerf_cli.rendering.options import RenderOptions
from insertnerf_cli.rendering.view_renderer import ViewRenderer, load_model
from insertnerf_cli.scenes import Scene

# Below this many items per process a child's start-up (a few seconds) outweighs what it renders.
ITEMS_PER_WORKER = 3
# Processes at most: each holds its own model, encodings and per-chunk tensors (about 0.6 GB at 256 px).
MAX_WORKERS = 8
_POLL_S = 0.1


class Work(Protocol):
    """What is done for one item (a picklable object: children receive it)."""

    def run(self, renderer: ViewRenderer, item: int) -> Any: ...


@dataclass(frozen=True)
class RendererSpec:
    """What a child needs to build the parent's ViewRenderer (ViewRenderer's arguments, the weights as a file)."""

    checkpoint: Path
    scene: Scene
    size: tuple[int, int]
    views: int
    device: str
    chunk: int | None
    exact: bool
    sfm_depth: bool
    options: RenderOptions

    def build(self, model: torch.nn.Module | None = None) -> ViewRenderer:
        """The ViewRenderer, with ``model`` where the caller has the weights loaded already (else from the file)."""
        model = load_model(self.checkpoint, self.device) if model is None else model
        return ViewRenderer(model, self.scene, self.size, self.views, self.device, self.chunk, self.exact,
                            self.sfm_depth, self.options)


def worker_count(requested: int | None, items: int, device: str) -> int:
    """Processes to do ``items`` items with: ``requested`` (at most one per item), else on a CPU one per core torch
    may use, while each gets ITEMS_PER_WORKER items, at most MAX_WORKERS; on a GPU one."""
    if requested is not None:
        return max(1, min(requested, items))
    if torch.device(device).type != "cpu":
        return 1
    return max(1, min(torch.get_num_threads(), items // ITEMS_PER_WORKER, MAX_WORKERS))


def run_side_by_side(renderer: ViewRenderer, spec: RendererSpec, work: Work, todo: list[int],
                     workers: int) -> Iterator[tuple[int, Any, int]]:
    """Do ``work`` for every item of ``todo``, yielding (item, its result, who: 0 for this process, n for child n)
    as each is done: here with ``renderer`` alone when ``workers`` is 1, else here on one thread and in
    ``workers`` - 1 spawned children (each with ``spec.build()``) on one thread each. Ctrl-C (or any error here)
    kills the children at once and goes on up."""
    if workers <= 1 or len(todo) < 2:
        for item in todo:
            yield item, work.run(renderer, item), 0
        return
    context = multiprocessing.get_context("spawn")
    # todo[front:back] is still to claim: this process takes from the front, the children from the back.
    front, back = context.Value("i", 0, lock=False), context.Value("i", len(todo), lock=False)
    lock, results = context.Lock(), context.Queue()
    children = [context.Process(target=_child, name=f"insertnerf-worker-{n}", daemon=True,
                                args=(n, os.getpid(), spec, work, todo, front, back, lock, results))
                for n in range(1, workers)]
    threads = torch.get_num_threads()
    reported: set[int] = set()
    try:
        for child in children:
            child.start()
        torch.set_num_threads(1)
        while (position := _claim(front, back, lock, from_front=True)) is not None:
            reported.add(todo[position])
            yield todo[position], work.run(renderer, todo[position]), 0
            for done in _finished(results, timeout=None):
                reported.add(done[0])
                yield done
        # Wait only for items a child is still on: one still starting up has none and is stopped below.
        while len(reported) < len(todo) and any(child.is_alive() for child in children):
            for done in _finished(results, timeout=_POLL_S):
                reported.add(done[0])
                yield done
    finally:
        torch.set_num_threads(threads)
        for child in children:
            if child.pid is None:  # never started (an interrupt during the others' start)
                continue
            if child.is_alive():
                child.kill()
            child.join()
        results.close()
    for item in todo:  # claimed by a child that failed or died before reporting it
        if item not in reported:
            yield item, work.run(renderer, item), 0


def _claim(front, back, lock, from_front: bool) -> int | None:
    """The next position of todo to do (from its front or its back), or None when none is left."""
    with lock:
        if front.value >= back.value:
            return None
        if from_front:
            front.value += 1
            return front.value - 1
        back.value -= 1
        return back.value


def _finished(results, timeout: float | None) -> Iterator[tuple[int, Any, int]]:
    """The (item, result, child) the children have sent: those waiting now, or the first within ``timeout``."""
    while True:
        try:
            message = results.get(timeout=timeout) if timeout is not None else results.get_nowait()
        except queue.Empty:
            return
        timeout = None
        if message is not None:
            yield message


def _child(number: int, parent: int, spec: RendererSpec, work: Work, todo: list[int], front, back, lock,
           results) -> None:
    """Child ``number``'s loop: claim items from the back of ``todo``, do each, send (item, result, number).
    Ctrl-C is the parent's to handle (it kills this process), and the kernel kills it when the ``parent``
    process dies; a failure here ends the loop quietly, and the parent does what is left."""
    become_child(parent)
    torch.set_num_threads(1)
    try:
        renderer = spec.build()
        while (position := _claim(front, back, lock, from_front=False)) is not None:
            results.put((todo[position], work.run(renderer, todo[position]), number))
    except Exception:  # noqa: BLE001 - the parent does the items this child left
        results.put(None)
    finally:
        results.close()
        results.join_thread()
        os._exit(0)  # no interpreter teardown: nothing of this process needs it, and it can hang on torch's pools
