"""``python -m lunar_drake.cli``: the ``lunar-drake`` program."""

from lunar_drake.cli import run

if __name__ == "__main__":
    run()
