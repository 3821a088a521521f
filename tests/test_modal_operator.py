"""The modal machinery of ProgressOperator, driven with synthetic events (headless Blender has no
event loop): progress reaches the status line and progress bar, Esc cancels and closes the core
generator, errors surface as reports."""

from __future__ import annotations

from types import SimpleNamespace

from blender_mrvm.errors import InputError
from blender_mrvm.operators._modal import ProgressOperator
from blender_mrvm.progress import Progress


class FakeWM:
    def __init__(self):
        self.calls = []

    def progress_begin(self, a, b):
        self.calls.append(("begin", a, b))

    def progress_update(self, v):
        self.calls.append(("update", v))

    def progress_end(self):
        self.calls.append(("end",))

    def event_timer_add(self, interval, window=None):
        self.calls.append(("timer_add",))
        return object()

    def event_timer_remove(self, timer):
        self.calls.append(("timer_remove",))

    def modal_handler_add(self, op):
        self.calls.append(("modal",))


class FakeWorkspace:
    def __init__(self):
        self.text = None

    def status_text_set(self, text):
        self.text = text


def make_context():
    props = SimpleNamespace(running=False, progress=0.0, status="")
    return SimpleNamespace(scene=SimpleNamespace(job=props), window_manager=FakeWM(), window=None,
                           workspace=FakeWorkspace(), screen=None)


class Job(ProgressOperator):
    props_attr = "job"
    job_name = "Test job"
    cancel_hint = "kept 2 things"

    def __init__(self, n=3, fail_at=None, error=None):
        self.n, self.fail_at, self.reports, self.closed = n, fail_at, [], False
        self.error = error or InputError("broken input at step 1")

    def report(self, level, msg):
        self.reports.append((next(iter(level)), msg))

    def start(self, context):
        def gen():
            try:
                yield Progress(0, self.n, "start")
                for i in range(self.n):
                    if i == self.fail_at:
                        raise self.error
                    yield Progress(i + 1, self.n, f"step {i + 1}")
                return "result"
            finally:
                self.closed = True
        return gen()

    def on_result(self, context, result):
        self.result_scene = context.scene
        assert context.window_manager is not None  # the rest of the context is the window's
        return f"done with {result}"


TIMER = SimpleNamespace(type="TIMER")


def test_modal_runs_to_the_end():
    ctx, op = make_context(), Job()
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"}
    props = ctx.scene.job
    assert props.running and props.status == "start"
    assert op.modal(ctx, SimpleNamespace(type="MOUSEMOVE")) == {"PASS_THROUGH"}
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    assert props.status == "step 1 (1/3), Esc to cancel" and abs(props.progress - 1 / 3) < 1e-9
    assert ctx.workspace.text == "MRVM: step 1 (1/3), Esc to cancel"
    results = [op.modal(ctx, TIMER) for _ in range(3)]
    assert results == [{"RUNNING_MODAL"}, {"RUNNING_MODAL"}, {"FINISHED"}]
    assert not props.running and props.status == "done with result" and ctx.workspace.text is None
    calls = ctx.window_manager.calls
    assert ("update", 1000) in calls and ("timer_remove",) in calls and calls[-1] == ("end",)
    assert op.reports[-1] == ("INFO", "done with result") and op.closed


def test_escape_cancels_and_closes_the_generator():
    ctx, op = make_context(), Job(n=10)
    op.invoke(ctx, None)
    op.modal(ctx, TIMER)
    assert op.modal(ctx, SimpleNamespace(type="ESC")) == {"CANCELLED"}
    assert op.closed and not ctx.scene.job.running
    assert op.reports[-1] == ("WARNING", "Test job cancelled; kept 2 things")
    assert ("end",) in ctx.window_manager.calls and ("timer_remove",) in ctx.window_manager.calls


class WorkerJob(Job):
    """A job run in the worker: its generator winds down over a few ticks once INTERRUPT is sent in (as
    worker.run_worker does while the child saves its step in progress), then raises Cancelled."""

    stops_softly = True

    def start(self, context):
        from blender_mrvm.errors import Cancelled
        from blender_mrvm.worker import INTERRUPT

        def gen():
            try:
                got = yield Progress(0, self.n, "start")
                for i in range(self.n):
                    if got == INTERRUPT:
                        self.interrupted = True
                        yield Progress(i, self.n, "stopping: saving the step")
                        raise Cancelled("the worker was interrupted; finished work is kept")
                    got = yield Progress(i + 1, self.n, f"step {i + 1}")
                return "result"
            finally:
                self.closed = True
        return gen()


def test_escape_on_a_worker_job_lets_it_wind_down_without_blocking():
    """Esc closed the generator, which waited for the worker to save its step (Train: up to 37 s, the UI frozen).
    A worker job is interrupted at the next tick and goes on until the worker has wound down; a second Esc stops
    it at once."""
    ctx, op = make_context(), WorkerJob(n=10)
    op.invoke(ctx, None)
    op.modal(ctx, TIMER)
    assert op.modal(ctx, SimpleNamespace(type="ESC")) == {"RUNNING_MODAL"}
    assert not op.closed and ctx.scene.job.running and "Esc again stops at once" in ctx.scene.job.status
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"} and op.interrupted  # sent in, winding down
    assert op.modal(ctx, TIMER) == {"CANCELLED"}
    assert op.closed and not ctx.scene.job.running
    assert op.reports[-1] == ("WARNING", "Test job cancelled; kept 2 things")

    ctx, op = make_context(), WorkerJob(n=10)
    op.invoke(ctx, None)
    op.modal(ctx, SimpleNamespace(type="ESC"))
    assert op.modal(ctx, SimpleNamespace(type="ESC")) == {"CANCELLED"} and op.closed  # the second Esc


def test_errors_are_reported_and_stop_the_job():
    ctx, op = make_context(), Job(n=3, fail_at=1)
    op.invoke(ctx, None)
    op.modal(ctx, TIMER)
    assert op.modal(ctx, TIMER) == {"CANCELLED"}
    assert op.reports[-1] == ("ERROR", "broken input at step 1") and not ctx.scene.job.running
    # a second job while one runs is refused
    ctx2, a, b = make_context(), Job(), Job()
    a.invoke(ctx2, None)
    assert b.invoke(ctx2, None) == {"CANCELLED"} and b.reports[-1][0] == "WARNING"


def test_execute_runs_synchronously():
    ctx, op = make_context(), Job()
    assert op.execute(ctx) == {"FINISHED"} and ctx.scene.job.status == "done with result"
    ctx, op = make_context(), Job(fail_at=0)
    assert op.execute(ctx) == {"CANCELLED"} and op.reports[-1] == ("ERROR", "broken input at step 1")


def test_an_unexpected_error_ends_the_job_so_the_next_run_starts():
    """Not an MRVMError (a bug, a module Blender's Python lacks): before, it escaped ``modal``, leaving the running
    flag set ("already running" on every later press), the timer firing and the progress bar up."""
    ctx, op = make_context(), Job(n=3, fail_at=1, error=ModuleNotFoundError("No module named 'OpenEXR'", name="OpenEXR"))
    op.invoke(ctx, None)
    op.modal(ctx, TIMER)
    assert op.modal(ctx, TIMER) == {"CANCELLED"}
    props, calls = ctx.scene.job, ctx.window_manager.calls
    assert not props.running and ("timer_remove",) in calls and calls[-1] == ("end",) and op.closed
    level, msg = op.reports[-1]
    assert level == "ERROR" and "Blender's Python has no module 'OpenEXR'" in msg and "build-extension" in msg
    assert props.status == msg
    again = Job()
    assert again.invoke(ctx, None) == {"RUNNING_MODAL"}  # not "already running"

    ctx, op = make_context(), Job(n=3, fail_at=0, error=ZeroDivisionError("division by zero"))
    op.invoke(ctx, None)
    assert op.modal(ctx, TIMER) == {"CANCELLED"} and not ctx.scene.job.running
    assert op.reports[-1] == ("ERROR", "unexpected error, a bug (ZeroDivisionError: division by zero); the traceback "
                                       "is in Blender's system console")
    # scripts (execute): a missing module reads the same; other errors still raise to the script
    ctx, op = make_context(), Job(fail_at=0, error=ModuleNotFoundError("No module named 'PIL'", name="PIL"))
    assert op.execute(ctx) == {"CANCELLED"} and "no module 'PIL'" in op.reports[-1][1]


def test_a_job_ends_in_the_scene_it_was_started_in():
    """The user shows another scene while the job runs: the job's progress, its end and its result stay with the
    scene it was started in (before, that scene stayed "running" and the result went to the one shown)."""
    ctx, op = make_context(), Job()
    a = ctx.scene
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"}
    b = ctx.scene = SimpleNamespace(job=SimpleNamespace(running=False, progress=0.0, status=""))
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"} and a.job.status.startswith("step 1") and b.job.status == ""
    while op.modal(ctx, TIMER) == {"RUNNING_MODAL"}:
        pass
    assert not a.job.running and a.job.status == "done with result" and op.result_scene is a
    assert b.job.status == "" and not b.job.running
    ctx.scene = a
    assert Job().invoke(ctx, None) == {"RUNNING_MODAL"}  # not "already running"


def test_a_job_whose_scene_was_deleted_is_cancelled(empty_scene):
    """A real scene: deleted while its job runs, the job is cancelled (generator closed, timer and progress bar
    ended) without touching the scene shown; one reallocated (undo) is found again by its session_uid."""
    import bpy

    job_scene = bpy.data.scenes.new("Job scene")
    ctx = make_context()
    ctx.scene = job_scene
    op = Job(n=5)
    op.props_attr = "mrvm_sem2nerf"
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and job_scene.mrvm_sem2nerf.running
    ctx.scene = empty_scene
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    stale = bpy.data.scenes.new("Stale")
    op._scene, op._scene_uid = stale, job_scene.session_uid
    bpy.data.scenes.remove(stale)
    assert op._job_scene(ctx) == job_scene  # found again by its session_uid
    bpy.data.scenes.remove(job_scene)
    assert op.modal(ctx, TIMER) == {"CANCELLED"} and op.closed
    assert op.reports[-1] == ("WARNING", "Test job cancelled: the scene it was started in was deleted")
    assert ctx.window_manager.calls[-1] == ("end",) and not empty_scene.mrvm_sem2nerf.running
    assert empty_scene.mrvm_sem2nerf.status == ""


def test_unregistering_the_addon_ends_its_running_jobs(addon):
    """Disabling the add-on while a job runs: Blender frees a running modal operator whose class is unregistered
    without calling its ``cancel`` (WM_operator_handlers_clear), so before, the worker went on running, the timer
    and the progress bar stayed and the section stayed "running". unregister() now ends each live job first, as
    Esc does (generator closed: the worker is interrupted), in the context the job was started in."""
    import blender_mrvm
    from blender_mrvm.operators import _modal

    ctx, op = make_context(), Job(n=10)
    done_ctx, done = make_context(), Job(n=1)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and done.invoke(done_ctx, None) == {"RUNNING_MODAL"}
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    while done.modal(done_ctx, TIMER) == {"RUNNING_MODAL"}:
        pass
    assert (None, "job") in _modal.live_sections()
    assert any(j is op for j in _modal._live) and not any(j is done for j in _modal._live)  # a finished one is not
    blender_mrvm.unregister()
    try:
        assert op.closed and not ctx.scene.job.running
        assert ctx.scene.job.status == op.reports[-1][1] == "Test job cancelled: the add-on was disabled; kept 2 things"
        calls = ctx.window_manager.calls
        assert ("timer_remove",) in calls and calls[-1] == ("end",) and ctx.workspace.text is None
        assert done_ctx.window_manager.calls.count(("end",)) == 1  # the finished one is left alone
        assert op.modal(ctx, TIMER) == {"CANCELLED"} and _modal.end_live_jobs() == 0
        op.cancel(ctx)  # Blender closing it later changes nothing
        assert calls.count(("end",)) == 1
    finally:
        blender_mrvm.register()
