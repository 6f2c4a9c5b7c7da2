"""Running a stylization: in place when Blender has no window (background
mode: tests, farm scripts), else in a worker thread while Blender's event
loop runs, with the progress in the panel, and Esc to cancel.

A task (operators.py) prepares from the scene, computes in `work(progress)`
without touching Blender's data, then either `commit`s the result to the
scene or `rollback`s everything it did, so a failed or cancelled run leaves
the scene and the files as they were."""

import threading

import bpy


class Cancelled(Exception):
    """Raised by the progress callback once Esc was pressed. The library
    stops the job at its next step and raises it again."""

    def __str__(self):
        return "cancelled"


class Run:
    """A task computing in a worker thread. The modal operator hands every
    event to `event`; the state it returns is the operator's."""

    def __init__(self, task):
        self.task = task
        self.done, self.total, self.message = 0, 0, ""
        self.result, self.error = None, None
        self.cancelled = False
        self.report = None  # (level, message) once the run ended
        s = task.settings()
        self._before = (s.progress, s.message)
        s.progress, s.message = 0.0, "starting"
        self.thread = threading.Thread(target=self._work, daemon=True)
        self.thread.start()

    def _progress(self, done, total, message):
        # The worker thread: no access to Blender's data here.
        if self.cancelled:
            raise Cancelled()
        self.done, self.total, self.message = done, total, message

    def _work(self):
        try:
            self.result = self.task.work(self._progress)
        except BaseException as e:  # reported in Blender's UI, never lost
            self.error = e

    def cancel(self):
        """Asks the job to stop at its next step (the main thread)."""
        self.cancelled = True

    def event(self, event_type, event_value):
        """One event: Esc cancels (and is consumed), a timer tick shows the
        progress and ends the run once the worker is done."""
        s = self.task.settings()
        if event_type == "ESC":
            if event_value == "PRESS" and not self.cancelled:
                self.cancel()
                if s is not None:
                    s.message = "cancelling"
            return {"RUNNING_MODAL"}
        if event_type != "TIMER":
            return {"PASS_THROUGH"}
        if s is not None and self.total and not self.cancelled:
            s.progress, s.message = self.done / self.total, self.message
        if self.thread.is_alive():
            return {"RUNNING_MODAL"}
        return self.end()

    def end(self):
        """Commits the result, or rolls the run back (cancelled or failed)."""
        s = self.task.settings()
        if self.cancelled or self.error is not None:
            self.task.rollback()
            if s is not None:
                s.progress, s.message = self._before
            if self.cancelled:
                self.report = ({"WARNING"}, "nst3d: cancelled; the scene is as it was")
            else:
                self.report = ({"ERROR"}, one_line(self.error))
            return {"CANCELLED"}
        try:
            self.report = ({"INFO"}, self.task.commit(self.result))
        except Exception as e:
            self.task.rollback()
            self.report = ({"ERROR"}, one_line(e))
            return {"CANCELLED"}
        if s is not None:
            s.progress, s.message = 1.0, "done"
        return {"FINISHED"}

    def stop(self):
        """Ends the run now (Blender cancels the operator: a file is loaded,
        the window closes): stops the job, waits for it, and removes the
        files it wrote. The scene may already be another one: left alone."""
        self.cancel()
        self.thread.join()
        self.task.rollback(scene=False)


def one_line(e):
    """The error's message for Blender's report: one line, no traceback."""
    text = str(e).strip() or type(e).__name__
    return text.splitlines()[-1]


class JobOperator:
    """The operators' shared half: `task_class(context)` prepares a task;
    `execute` runs it in place (background) or starts a `Run` and goes
    modal."""

    task_class = None
    _run = None
    _timer = None

    def execute(self, context):
        try:
            task = self.task_class(context)
        except Exception as e:
            self.report({"ERROR"}, one_line(e))
            return {"CANCELLED"}
        if bpy.app.background or context.window is None:
            return self._run_in_place(context, task)
        wm = context.window_manager
        self._run = Run(task)
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, 1)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _run_in_place(self, context, task):
        wm = context.window_manager
        wm.progress_begin(0, 1)

        def progress(done, total, message):
            if total:
                wm.progress_update(done / total)
                print(f"nst3d: [{done}/{total}] {message}", flush=True)

        try:
            result = task.work(progress)
            message = task.commit(result)
        except BaseException as e:  # Ctrl-C too: the scene is put back first
            task.rollback()
            if not isinstance(e, Exception):
                raise
            self.report({"ERROR"}, one_line(e))
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def modal(self, context, event):
        state = self._run.event(event.type, event.value)
        if state & {"RUNNING_MODAL", "PASS_THROUGH"}:
            if self._run.total:
                context.window_manager.progress_update(self._run.done / self._run.total)
            for area in context.screen.areas if context.screen else ():
                area.tag_redraw()
            return state
        self._end(context)
        self.report(*self._run.report)
        return state

    def cancel(self, context):
        self._run.stop()
        self._end(context)

    def _end(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
