"""Exception types shared by every seft package.

The command-line interface maps each of them to a one-line message and exit code 2
(house style after ``rosbags/rosbag2/errors.py``).
"""

__all__ = ['SeftError', 'InputError', 'ParameterError', 'RigLimitError', 'Interrupted']


class SeftError(Exception):
    """Base class of every error seft reports to a user as a one-line message."""


class InputError(SeftError):
    """A file given by the user (record, CSV, bag, YAML) is missing or malformed.

    The message names the file (and line or field where known) and what was expected.
    """


class ParameterError(SeftError):
    """A parameter value is out of its documented range or of the wrong type.

    The message names the parameter and what was expected.
    """


class RigLimitError(SeftError):
    """The rig left its safe envelope (stroke or force limit); the run was aborted."""


class Interrupted(KeyboardInterrupt):
    """A command stopped by Ctrl-C, SIGTERM or SIGHUP, with what it had reached.

    A ``KeyboardInterrupt``, so that every ``except KeyboardInterrupt`` on its way still
    takes it.

    Parameters
    ----------
    signame : str
        The signal (``SIGINT``, ``SIGTERM``, ``SIGHUP``).
    state : str
        What the command had reached when it stopped, as the end of the sentence
        ``seft: interrupted by SIGINT: <state>`` (the run's ending: the rig's safe state,
        the bag; what was written and what was not).
    """

    def __init__(self, signame: str, state: str):
        super().__init__(signame, state)
        self.signame = signame
        self.state = state
