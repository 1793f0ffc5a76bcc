"""scmpc roles in Python: the message layouts and the role runtime.

A role process of scmpc written in Python, on iceoryx2's own Python bindings
(``iceoryx2==0.10.0``, the version of the Rust side). Write a step function and hand it to
:meth:`runtime.Link.run`; ``examples/python/estimator.py`` is a whole estimator.
"""

from . import messages, runtime
from .messages import *  # noqa: F401,F403
from .runtime import Link, RoleArgs, keep_newest, monotonic_ns  # noqa: F401
