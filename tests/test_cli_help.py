"""Every option of every command has help text, and every command's ``--help`` ends with an
example.

The parser (:func:`thinfilm.cli.build_parser`) is walked command by command
(:func:`thinfilm.cli.commands`): an argument without help, or a (sub)command whose epilog
holds no ``thinfilm ...`` example line, fails. The checkers run on a small bad parser first,
so that they cannot pass by seeing nothing.
"""

import argparse

import pytest

from thinfilm.cli import arguments, build_parser, commands, main, subcommands


def missing_help(parser):
    """The flags or names of the arguments of ``parser`` that have no help text."""
    out = []
    for action in arguments(parser):
        if action.choices is not None and set(action.choices) == set(subcommands(parser)) and subcommands(parser):
            continue  # the subcommands: each one's help is checked below
        if not (action.help or "").strip() or action.help == argparse.SUPPRESS:
            out.append("/".join(action.option_strings) or action.dest)
    out.extend(name for name, text in subcommands(parser).items() if not (text or "").strip())
    return out


def has_example(parser):
    epilog = parser.epilog or ""
    return (isinstance(parser.formatter_class, type)
            and issubclass(parser.formatter_class, argparse.RawDescriptionHelpFormatter)
            and any(line.strip().startswith("thinfilm ") for line in epilog.splitlines()))


def test_the_checkers_catch_what_they_are_for():
    bad = argparse.ArgumentParser(prog="thinfilm")
    bad.add_argument("--quiet", action="store_true")
    bad.add_argument("--fine", help="has help")
    sub = bad.add_subparsers(dest="command")
    sub.add_parser("nohelp")
    assert missing_help(bad) == ["--quiet", "nohelp"]
    assert not has_example(bad)
    good = argparse.ArgumentParser(prog="thinfilm", epilog="examples:\n  thinfilm x --out y",
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    assert has_example(good)
    assert [name for name, _ in commands(bad)] == ["thinfilm", "thinfilm nohelp"]


def test_the_walk_sees_every_command():
    names = {name for name, _ in commands()}
    assert {"thinfilm", "thinfilm render", "thinfilm generate", "thinfilm reconstruct",
            "thinfilm reconstruct rgb", "thinfilm reconstruct spectral", "thinfilm methods",
            "thinfilm evaluate", "thinfilm benchmark", "thinfilm fit-spectrum", "thinfilm import",
            "thinfilm import polarization", "thinfilm import spectral"} <= names


@pytest.mark.parametrize("name", [name for name, _ in commands()])
def test_every_option_has_help(name):
    parser = dict(commands())[name]
    assert not missing_help(parser), f"{name}: arguments without help: {missing_help(parser)}"


@pytest.mark.parametrize("name", [name for name, _ in commands()])
def test_every_command_shows_an_example(name, capsys):
    parser = dict(commands())[name]
    assert has_example(parser), f"{name}: its epilog holds no 'thinfilm ...' example"
    argv = name.split()[1:] + ["--help"]
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 0
    shown = capsys.readouterr().out
    assert "examples:\n  thinfilm " in shown   # kept as written (not re-wrapped)
    assert all(("  " + line.strip()) in shown for line in parser.epilog.splitlines()[1:])


def test_the_parser_is_the_one_of_the_command():
    assert build_parser().prog == "thinfilm"
