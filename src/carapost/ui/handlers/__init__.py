"""Menu handlers, one module per menu: file, edit, process, navigation, view, inspect, help.

Every handler is a plain function taking the :class:`~carapost.ui.context.ActionContext`
(checkable items get the new state as a second argument); the action table
(:mod:`carapost.ui.actions`) binds the rest with :func:`functools.partial`. A handler
reads the project, asks through ``ctx.dialogs`` and changes data only through the open
project's :class:`~carapost.session.Session`: ``ctx.act(title, ctx.session.method,
...)``, ``ctx.session.prepare`` + ``ctx.runner.start_job`` + ``ctx.apply`` for Process
work (:func:`carapost.ui.handlers.process.run`), or ``ctx.set_session`` for a new
project. No handler reads a file or builds a command itself.
"""
