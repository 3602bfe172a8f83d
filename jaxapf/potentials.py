"""The potentials' public contract at its first import path; they live in :mod:`jaxapf.planners.potentials`."""

from .planners.potentials import *  # noqa: F401,F403
from .planners.potentials import __all__  # noqa: F401
