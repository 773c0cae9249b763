"""Menu handlers, one module per menu: file, edit, process, navigation, view, inspect, help.

Every handler is a plain function whose first argument is the
:class:`~carapost.ui.context.ActionContext` (checkable items get the new state as a
second argument); the action table (:mod:`carapost.ui.actions`) binds the rest with
:func:`functools.partial`. A handler reads the project, asks through ``ctx.dialogs``
and changes data only through ``ctx.push(command)``, ``ctx.run_job(title, fn, done)``
or ``ctx.set_project(project)``, never through the window.
"""
