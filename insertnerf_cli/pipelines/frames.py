"""A render's frames, written one by one, on one process or on several side by side (no click here).

On a CPU, whole frames in separate processes beat one frame's chunks on separate threads: a chunk makes about a
thousand small torch calls, and between them two threads take turns at Python's global lock. Two one-thread
processes scale to 1.95x one thread where two threads reach 1.6-1.7x; room's 30 frames took 0.76-0.94x the time
of one two-thread process, with the pixels of a one-thread render (docs/research-log.md, Speed). The parent
renders frames too, from the front of the list, while spawned children take them from the back, so a child's
start-up (importing torch and this package, a few seconds) costs nothing but its own late start, and consecutive
frames, which share their reference views' encodings, stay on one process. Every frame is written by whoever
rendered it (its colour file last, which marks it done); a frame a child claimed but never wrote (the child
failed or died) is rendered by the parent at the end.
"""
from __future__ import annotations

import multiprocessing
import os
import queue
import signal
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import torch

from insertnerf_cli.exporters.outputs import depth_to_float, depth_to_turbo, depth_to_uint16, frame_paths, write_frame
from insertnerf_cli.poses.child import die_with_parent
from insertnerf_cli.rendering.camera_paths import CameraPath
from insertnerf_cli.rendering.options import RenderOptions
from insertnerf_cli.rendering.view_renderer import ViewRenderer, load_model
from insertnerf_cli.scenes import Scene

# Below this many frames per process a child's start-up (a few seconds) outweighs what it renders.
FRAMES_PER_WORKER = 3
# Processes at most: each holds its own model, encodings and per-chunk tensors (about 0.6 GB at 256 px).
MAX_WORKERS = 8
# Below half opacity a pixel shows mostly background, so its depth says little: it is written as invalid.
MIN_DEPTH_OPACITY = 0.5
_POLL_S = 0.1


@dataclass(frozen=True)
class FrameWriter:
    """How a rendered frame becomes its three files in ``out_dir`` (outputs.frame_paths): depth in the scene's
    units (``similarity_scale``: normalised units per scene unit), stored as ``depth_format`` with
    ``depth_scale``, and a turbo picture of it between the path's ``near`` and ``far``."""

    out_dir: Path
    similarity_scale: float
    depth_scale: float
    depth_format: str
    near: float
    far: float

    def render(self, renderer: ViewRenderer, path: CameraPath, index: int) -> int:
        """Render frame ``index`` of ``path`` and write its files; returns the depth pixels clipped (0 by
        construction of depth_scale)."""
        out, _ = renderer.render(path.cameras.subset([index]), float(path.near[index]), float(path.far[index]),
                                 excluded_views(path, index))
        depth = out.depth.double().cpu().numpy()
        valid = out.opacity.cpu().numpy() >= MIN_DEPTH_OPACITY
        if self.depth_format == "npy":
            stored, clipped = depth_to_float(depth / self.similarity_scale, valid), 0
        else:
            stored, clipped = depth_to_uint16(depth / self.similarity_scale, valid, self.depth_scale)
        write_frame(frame_paths(self.out_dir, index, self.depth_format), out.rgb.float().cpu().numpy(), stored,
                    depth_to_turbo(depth, valid, self.near, self.far))
        return clipped

    def done(self, index: int) -> bool:
        return frame_paths(self.out_dir, index, self.depth_format).all_exist()


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

    def build(self) -> ViewRenderer:
        return ViewRenderer(load_model(self.checkpoint, self.device), self.scene, self.size, self.views, self.device,
                            self.chunk, self.exact, self.sfm_depth, self.options)


def excluded_views(path: CameraPath, frame: int) -> list[int]:
    """The input views frame ``frame`` may not be rendered from: for the "input" path, the photo it re-renders."""
    return [path.source_index[frame]] if path.source_index is not None else []


def frame_workers(requested: int | None, frames: int, device: str) -> int:
    """Processes to render ``frames`` frames with: ``requested`` (at most one per frame), else on a CPU one per
    core torch may use, while each gets FRAMES_PER_WORKER frames, at most MAX_WORKERS; on a GPU one."""
    if requested is not None:
        return max(1, min(requested, frames))
    if torch.device(device).type != "cpu":
        return 1
    return max(1, min(torch.get_num_threads(), frames // FRAMES_PER_WORKER, MAX_WORKERS))


def render_frames(renderer: ViewRenderer, spec: RendererSpec, path: CameraPath, writer: FrameWriter,
                  todo: list[int], workers: int) -> Iterator[tuple[int, int, int]]:
    """Render and write the frames ``todo`` of ``path``, yielding (frame, clipped depth pixels, who: 0 for this
    process, n for child n) as each is written: here with ``renderer`` alone when ``workers`` is 1, else here on
    one thread and in ``workers`` - 1 spawned children with one thread each. Ctrl-C (or any error here) kills the
    children at once and goes on up."""
    if workers <= 1 or len(todo) < 2:
        for index in todo:
            yield index, writer.render(renderer, path, index), 0
        return
    context = multiprocessing.get_context("spawn")
    # todo[front:back] is still to claim: this process takes from the front, the children from the back.
    front, back = context.Value("i", 0, lock=False), context.Value("i", len(todo), lock=False)
    lock, results = context.Lock(), context.Queue()
    children = [context.Process(target=_child, name=f"insertnerf-frames-{n}", daemon=True,
                                args=(n, os.getpid(), spec, path, writer, todo, front, back, lock, results))
                for n in range(1, workers)]
    threads = torch.get_num_threads()
    try:
        for child in children:
            child.start()
        torch.set_num_threads(1)
        reported: set[int] = set()
        while (position := _claim(front, back, lock, from_front=True)) is not None:
            reported.add(todo[position])
            yield todo[position], writer.render(renderer, path, todo[position]), 0
            for item in _finished(results, timeout=None):
                reported.add(item[0])
                yield item
        # Wait only for frames a child is still rendering: one still starting up has none and is stopped below.
        while len(reported) < len(todo) and any(child.is_alive() for child in children):
            for item in _finished(results, timeout=_POLL_S):
                reported.add(item[0])
                yield item
    finally:
        torch.set_num_threads(threads)
        for child in children:
            if child.pid is None:  # never started (an interrupt during the others' start)
                continue
            if child.is_alive():
                child.kill()
            child.join()
        results.close()
    for index in todo:  # claimed by a child that failed or died before writing it
        if not writer.done(index):
            yield index, writer.render(renderer, path, index), 0


def _claim(front, back, lock, from_front: bool) -> int | None:
    """The next position of todo to render (from its front or its back), or None when none is left."""
    with lock:
        if front.value >= back.value:
            return None
        if from_front:
            front.value += 1
            return front.value - 1
        back.value -= 1
        return back.value


def _finished(results, timeout: float | None) -> Iterator[tuple[int, int, int]]:
    """The (frame, clipped, child) results the children have sent: those waiting now, or the first within
    ``timeout``."""
    while True:
        try:
            item = results.get(timeout=timeout) if timeout is not None else results.get_nowait()
        except queue.Empty:
            return
        timeout = None
        if item is not None:
            yield item


def _child(number: int, parent: int, spec: RendererSpec, path: CameraPath, writer: FrameWriter, todo: list[int],
           front, back, lock, results) -> None:
    """Child ``number``'s loop: claim frames from the back of ``todo``, render and write each, send (frame,
    clipped, number). Ctrl-C is the parent's to handle (it kills this process), and the kernel kills it when the
    ``parent`` process dies; a failure here ends the loop quietly, and the parent renders what is left."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()
    if os.getppid() != parent:  # it died before the line above took effect: no one will use these frames
        os._exit(0)
    torch.set_num_threads(1)
    try:
        renderer = spec.build()
        while (position := _claim(front, back, lock, from_front=False)) is not None:
            results.put((todo[position], writer.render(renderer, path, todo[position]), number))
    except Exception:  # noqa: BLE001 - the parent renders the frames this child left
        results.put(None)
    finally:
        results.close()
        results.join_thread()
        os._exit(0)  # no interpreter teardown: nothing of this process needs it, and it can hang on torch's pools
