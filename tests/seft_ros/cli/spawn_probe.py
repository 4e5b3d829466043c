"""A stand-in node module for tests/seft_ros/cli/test_spawn.py: prints what a started node
sees (its arguments, an environment variable, its command line, what the garbage collector
holds), then sleeps or exits with the code its arguments give."""

import gc
from pathlib import Path
import sys
import time


def main() -> int:
    args = sys.argv[1:]
    print('argv', ' '.join(args))
    print('env', __import__('os').environ.get('SPAWN_PROBE', '<unset>'))
    print('cmdline', Path('/proc/self/cmdline').read_bytes().replace(b'\0', b' ').decode()
          .strip())
    # what the cyclic garbage collector holds: frozen (by the fork server) and tracked
    print('gc', gc.get_freeze_count(), len(gc.get_objects()))
    print('stderr too', file=sys.stderr)
    sys.stdout.flush()            # an executed probe's stdout, a file, is block-buffered
    if args and args[0] == 'sleep':
        time.sleep(float(args[1]))
        return 0
    return int(args[0]) if args else 0


if __name__ == '__main__':
    sys.exit(main())
