"""The one way operators run long work: a core progress generator (``progress.py``), driven

- modally from the UI (``invoke``): a timer advances the generator one step per tick, so the UI
  stays responsive; the panel's status line, Blender's progress indicator and the status bar show
  progress; Esc (or Blender closing the operator) cancels by closing the generator, whose
  ``finally`` blocks keep what was finished and clean up the rest;
- to the end in one call from scripts and ``--background`` (``execute``).

A subclass names the PropertyGroup on the scene that holds ``running``, ``progress`` and
``status`` (``props_attr``), starts its generator (``start``) and turns the generator's result into
scene changes and a message (``on_result``, on the main thread).

A job belongs to the scene it was started in: the window may show another scene by the time it ends,
so its progress, its end and its result go to that scene (``on_result`` gets a context whose ``scene``
is the job's), never to the scene shown then.
"""

from __future__ import annotations

import re
from types import SimpleNamespace

from ..errors import Cancelled, MRVMError

_PROGRESS_STEPS = 1000
_GONE = object()
"""``ProgressOperator._scene`` once the job's scene was deleted."""
_live: list = []
"""The modal jobs running now (their operators), so that :func:`end_live_jobs` can end them when the add-on is
unregistered."""


def unsaved_relative(*paths: str) -> bool:
    """Whether one of ``paths`` is relative to the .blend (``//``) while the .blend was never saved."""
    import bpy

    return not bpy.data.filepath and any(p.strip().startswith("//") for p in paths)


SAVE_FIRST = "Save the .blend first: {what} is relative to it (//), or choose an absolute folder"
"""The greyed-out button's reason when a ``//`` setting cannot be resolved (``what``: the setting's name)."""


def live_sections() -> set[tuple[int | None, str]]:
    """(scene ``session_uid``, section) of every modal job running now: sections whose ``running`` is true."""
    return {(job._scene_uid, job.props_attr) for job in _live}


def end_live_jobs(context=None, reason: str = "the add-on was disabled") -> int:
    """End every modal job still running; the add-on calls it when it is unregistered, before its operator classes
    go (Blender then frees a running modal operator without calling its ``cancel``, which would leave the worker
    process running, the timer firing, the progress indicator up and the section "running"). Each job's generator
    is closed (the worker is interrupted; finished work is kept, as with Esc), its timer removed, the progress
    indicator ended and its section set idle with a message naming ``reason`` and what was kept. ``context``: the
    one to end them in (default: the one each was started in). Returns how many jobs were ended."""
    n = 0
    while _live:
        job = _live.pop()
        try:
            gen, job._gen = job._gen, None
            if gen is not None:
                gen.close()
            hint = f"; {job.cancel_hint}" if job.cancel_hint else ""
            job._finish(job._started_in if context is None else context, True,
                        f"{job.job_name} cancelled: {reason}{hint}", "WARNING")
            n += 1
        except Exception as e:  # noqa: BLE001  (an operator Blender freed already: end the others)
            print(f"blender_mrvm: could not end {job.job_name}: {type(e).__name__}: {e}")
    return n


def unexpected_error(e: Exception) -> str:
    """The panel's message for an error that is not an :class:`MRVMError` (whose message is the user's to read):
    a module Blender's Python lacks says which, and why; anything else is named as a bug, its traceback printed to
    Blender's console."""
    if isinstance(e, ModuleNotFoundError) and e.name:
        return (f"Blender's Python has no module {e.name.split('.')[0]!r}: this copy of the extension was built "
                "without the packages it bundles (openexr, pillow, trimesh, assimp-py); build it with `python -m "
                "blender_mrvm build-extension` where the package index can be reached, and install that zip")
    import traceback

    traceback.print_exception(e)
    return f"unexpected error, a bug ({type(e).__name__}: {e}); the traceback is in Blender's system console"


_IN_THE_PANEL = re.compile(r"(?<![\w/.-])`?--[a-z][a-z0-9-]*`?(?: [^\s(;,]+)? \(in the panel: ([^)]+)\)")
"""A flag the message already names the panel's control for: ``use --force (in the panel: Overwrite)``."""
_COMMAND = re.compile(r"(`[^`]*\s[^`]*`)")
_FLAG = re.compile(r"(?<![\w/.-])`?(--[a-z][a-z0-9-]*(?: --[a-z][a-z0-9-]*)*)`?")


def in_panel_words(message: str, names: dict[str, str]) -> str:
    """``message`` (most come from the CLI's code, run in the worker or in Blender) with the command-line flags it
    names put in the panel's words: each flag of ``names`` (a flag, or several in a row such as ``--no-resume
    --force``) becomes the name of the panel's control in quotes; a flag followed by ``(in the panel: X)`` becomes
    X. Flags the panel has no control for stay as they are, and so does a command to run, in backquotes (such as
    the weights' ``python -m blender_mrvm fetch-weights --out DIR``)."""

    def word(m):
        run = m.group(1)
        if run in names:  # a run of flags the panel says in its own words (``--no-resume --force``)
            return names[run] if " " in run else f"'{names[run]}'"
        return " ".join(f"'{names[f]}'" if f in names else f for f in run.split())

    parts = _COMMAND.split(message)  # a command to run in a shell (`python -m ... --out DIR`) stays as it is
    return "".join(p if k % 2 else _FLAG.sub(word, _IN_THE_PANEL.sub(lambda m: m.group(1), p))
                   for k, p in enumerate(parts))


class ProgressOperator:
    panel_names: dict = {}
    """The command-line flags of the CLI code the job runs, by the names of this section's controls in the panel
    (:func:`in_panel_words`): its messages name what the artist sees."""
    props_attr: str = ""
    """Scene attribute of the PropertyGroup with running / progress / status."""
    job_name: str = "Job"
    """Used in messages: '<job_name> is already running', '<job_name> cancelled'."""
    cancel_hint: str = ""
    """Appended to the cancel message (what was kept)."""
    timer_interval: float = 0.01
    stops_softly: bool = False
    """The job runs in the worker (``worker.run_worker``): Esc interrupts it and the job goes on while the worker
    finishes and saves its step in progress (the UI stays free); a second Esc stops it at once."""

    _gen = None
    _timer = None
    _send = None
    """What the next timer tick sends into the job's generator (``worker.INTERRUPT`` after a first Esc)."""
    _stopping = False
    _scene = None
    """The scene the modal job was started in (None: ``context.scene``)."""
    _scene_uid = None
    _started_in = None
    """What :func:`end_live_jobs` ends a job in: the window manager, workspace and screen it was started from."""

    # -- to implement ---------------------------------------------------------------------
    def start(self, context):
        """Return the core progress generator (may raise MRVMError for bad settings)."""
        raise NotImplementedError

    def on_result(self, context, result) -> str:
        """Apply the generator's result on the main thread; return the success message."""
        raise NotImplementedError

    @classmethod
    def blocked(cls, context) -> str:
        """Why the job cannot start with these settings and this scene, in a line the panel shows on the greyed-out
        button ('' when it can): only what is cheap to check on every redraw (no file is read)."""
        return ""

    @classmethod
    def poll(cls, context):
        props = getattr(getattr(context, "scene", None), cls.props_attr, None)
        if props is None:
            return False
        why = "" if props.running else cls.blocked(context)  # running: the panel shows the progress bar instead
        if why:
            cls.poll_message_set(why)
        return not why

    def _say(self, message: str) -> str:
        return in_panel_words(message, self.panel_names)

    # -- shared machinery ---------------------------------------------------------------
    def _job_scene(self, context):
        """The scene the job runs for: the one it was started in (found again by its ``session_uid`` when undo
        reallocated it), or None when that scene was deleted; ``context.scene`` outside a modal job."""
        if self._scene is None:
            return context.scene
        if self._scene is _GONE:
            return None
        try:
            getattr(self._scene, self.props_attr)  # a scene removed (or reallocated by undo) raises ReferenceError
        except ReferenceError:
            import bpy

            self._scene = next((s for s in bpy.data.scenes if s.session_uid == self._scene_uid), _GONE)
        return None if self._scene is _GONE else self._scene

    def _job_context(self, context):
        """``context`` with the job's scene as ``context.scene`` (what ``on_result`` is given)."""
        scene = self._job_scene(context)
        return context if scene is None or scene is getattr(context, "scene", None) else _SceneContext(context, scene)

    def _props(self, context):
        scene = self._job_scene(context)
        return getattr(scene, self.props_attr) if scene is not None else None

    def _begin(self, context):
        gen = self.start(context)
        first = next(gen)  # the generator validates its input before any work
        return gen, first

    def execute(self, context):
        from ..progress import run_to_end

        props = self._props(context)
        try:
            gen, _ = self._begin(context)
            message = self.on_result(context, run_to_end(gen))
        except (MRVMError, ModuleNotFoundError) as e:
            props.status = self._say(str(e)) if isinstance(e, MRVMError) else unexpected_error(e)
            self.report({"ERROR"}, props.status)
            return {"CANCELLED"}
        message = self._say(message)
        props.status = message
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def invoke(self, context, event):
        props = self._props(context)
        if props.running or self._live_in(context.scene):
            self.report({"WARNING"}, f"{self.job_name} is already running")
            return {"CANCELLED"}
        try:
            self._gen, first = self._begin(context)
        except (MRVMError, ModuleNotFoundError) as e:
            props.status = self._say(str(e)) if isinstance(e, MRVMError) else unexpected_error(e)
            self.report({"ERROR"}, props.status)
            return {"CANCELLED"}
        props.running, props.progress, props.status = True, first.fraction, first.message
        self._scene, self._scene_uid = context.scene, getattr(context.scene, "session_uid", None)
        wm = context.window_manager
        wm.progress_begin(0, _PROGRESS_STEPS)
        self._timer = wm.event_timer_add(self.timer_interval, window=context.window)
        wm.modal_handler_add(self)
        self._started_in = SimpleNamespace(window_manager=wm, workspace=context.workspace, screen=context.screen,
                                           scene=context.scene)
        _live.append(self)
        return {"RUNNING_MODAL"}

    def _live_in(self, scene) -> bool:
        """Whether a job of this section runs in ``scene`` now, whatever its ``running`` says (a script, or a state
        of an undo step, may have set it idle: a second job would run beside the first, into its folders)."""
        uid = getattr(scene, "session_uid", None)
        return any(job.props_attr == self.props_attr and (job._scene is scene or uid is not None
                                                          and job._scene_uid == uid) for job in _live)

    def _finish(self, context, cancelled: bool, message: str, level: str = "INFO"):
        message = self._say(message)
        _live[:] = [job for job in _live if job is not self]
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.workspace:
            context.workspace.status_text_set(None)
        props = self._props(context)
        if props is not None:  # None: the job's scene was deleted
            props.running = False
            props.status = message
        self.report({level}, message)
        _redraw(context)
        return {"CANCELLED"} if cancelled else {"FINISHED"}

    def _cancel_message(self) -> str:
        return f"{self.job_name} cancelled" + (f"; {self.cancel_hint}" if self.cancel_hint else "")

    def cancel(self, context):  # Blender closing the operator (file load, quit)
        if not any(job is self for job in _live):  # ended already (end_live_jobs)
            return
        if self._gen is not None:
            self._gen.close()
        self._finish(context, True, self._cancel_message(), "WARNING")

    def modal(self, context, event):
        if self._gen is None:  # ended by end_live_jobs (the add-on was unregistered)
            return {"CANCELLED"}
        if event.type == "ESC":
            if self.stops_softly and not self._stopping:
                from ..worker import INTERRUPT

                self._stopping, self._send = True, INTERRUPT  # handled at the next tick; the UI is not blocked
                props = self._props(context)
                if props is not None:
                    props.status = f"stopping {self.job_name}: finishing the step in progress (Esc again stops at once)"
                return {"RUNNING_MODAL"}
            self._gen.close()
            return self._finish(context, True, self._cancel_message(), "WARNING")
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._props(context) is None:
            self._gen.close()
            return self._finish(context, True, f"{self.job_name} cancelled: the scene it was started in was deleted",
                                "WARNING")
        try:
            send, self._send = self._send, None
            ev = self._gen.send(send) if send is not None else next(self._gen)
        except StopIteration as stop:
            try:
                return self._finish(context, False, self.on_result(self._job_context(context), stop.value))
            except MRVMError as e:
                return self._finish(context, True, str(e), "ERROR")
            except Exception as e:  # the job must end: a running flag left set refuses every later run
                return self._finish(context, True, unexpected_error(e), "ERROR")
        except MRVMError as e:
            if self._stopping and isinstance(e, Cancelled):  # the worker wound down after Esc, as asked
                return self._finish(context, True, self._cancel_message(), "WARNING")
            return self._finish(context, True, str(e), "ERROR")
        except ReferenceError as e:  # the job's own Blender data (Render Dataset's scene) was freed under it: undo
            import traceback  # reloads the data saved before the job made it, or the artist deleted it

            traceback.print_exception(e)
            hint = f"; {self.cancel_hint}" if self.cancel_hint else ""
            return self._finish(context, True, f"{self.job_name} stopped: an undo (or a deletion) removed the Blender "
                                               f"data it was working on{hint}", "ERROR")
        except Exception as e:  # the generator has ended with it; the timer and the progress bar end here
            return self._finish(context, True, unexpected_error(e), "ERROR")
        props = self._props(context)
        count = f" ({ev.done}/{ev.total})" if ev.total else ""
        props.progress, props.status = ev.fraction, f"{ev.message}{count}, Esc to cancel"
        context.window_manager.progress_update(int(ev.fraction * _PROGRESS_STEPS))
        if context.workspace:
            context.workspace.status_text_set(f"MRVM: {props.status}")
        _redraw(context, "VIEW_3D")
        return {"RUNNING_MODAL"}


class _SceneContext:
    """A context whose ``scene`` is another one (the job's); everything else is the context's."""

    def __init__(self, context, scene):
        self._context, self.scene = context, scene

    def __getattr__(self, name):
        return getattr(self._context, name)


def _redraw(context, area_type: str | None = None) -> None:
    for area in context.screen.areas if context.screen else ():
        if area_type is None or area.type == area_type:
            area.tag_redraw()
