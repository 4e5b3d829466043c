"""The command-line parser of seft's commands: a bad argument is one error line (no traceback).

argparse prints the command's usage (several lines) before its error; a lab's terminal and
log then hold a block where every other input error of seft is one line naming what was
wrong (``seft: error: ...``, exit code 2). This parser prints that one line, with where the
options are listed, and nothing else.
"""

import argparse
import re
import sys

__all__ = ['OneLineParser']


class OneLineParser(argparse.ArgumentParser):
    """:class:`argparse.ArgumentParser` whose errors are one line on stderr and exit code 2.

    Parameters
    ----------
    *args, error_prefix : str, optional, **kwargs
        As :class:`argparse.ArgumentParser`; `error_prefix` starts the error line (default:
        the first word of ``prog``, e.g. ``seft`` for ``seft simulate``).

    Notes
    -----
    An argument a subcommand does not know is found by the top-level parser after the
    subcommand has parsed its own: :meth:`parse_args` reports it against the subcommand
    (``see 'seft simulate --help'``), not the top level.
    """

    def __init__(self, *args, error_prefix: str | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.error_prefix = error_prefix or self.prog.split()[0]
        self.verbs: dict = {}           # subcommand -> its parser (set by the caller)

    def error(self, message: str):
        """Print ``<prefix>: error: <message> (see '<prog> --help')`` and exit with code 2.

        A configuration file taken as a value of a list option (``--alpha 0.5 lab.yaml``:
        argparse's "invalid float value: 'lab.yaml'") gets the cure: the file first."""
        value = re.search(r"invalid \w+ value: '([^']*)'", message)
        if value and value.group(1).lower().endswith(('.yaml', '.yml')):
            message += (f' ({value.group(1)} taken as its value: an option of several values '
                        'takes every word after it; give the configuration file first)')
        print(f"{self.error_prefix}: error: {message} (see '{self.prog} --help')",
              file=sys.stderr)
        sys.exit(2)

    def parse_args(self, args=None, namespace=None):
        """As :meth:`argparse.ArgumentParser.parse_args`; an unknown argument is reported by
        the subcommand's parser when a subcommand was given (:attr:`verbs`), and one of its
        options given before it is said so (``seft --force simulate``)."""
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            verb = getattr(namespace, 'verb', None)
            parser = self.verbs.get(verb, self)
            before = [e for e in extras if parser is not self
                      and e.split('=', 1)[0] in parser._option_string_actions]
            where = (f" ({', '.join(before)}: an option of '{parser.prog}', given before "
                     "the verb: put it after the verb)" if before else '')
            parser.error(f'unrecognized arguments: {" ".join(extras)}{where}')
        return namespace
