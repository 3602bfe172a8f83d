"""The MPC's public contract at its first import path; it lives in :mod:`jaxapf.control.mpc`."""

from .control.mpc import *  # noqa: F401,F403
from .control.mpc import __all__  # noqa: F401
