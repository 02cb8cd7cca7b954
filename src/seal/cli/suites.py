"""`seal suites list|show|generate|check` (the work is in seal.suite_tools)."""

from __future__ import annotations

from seal.cli.common import COUNT, INDEX


def add(sub) -> None:
    suites = sub.add_parser("suites", help="evaluation suites: list, contact sheet, generate data, check")
    suites_sub = suites.add_subparsers(dest="suites_command", required=True)
    s_list = suites_sub.add_parser("list", help="suites, task counts, instructions and what each variant changes")
    s_list.add_argument("suite", nargs="?", default=None, help="one suite (default: all)")
    s_show = suites_sub.add_parser("show", help="contact sheet of every task's first frame (agent view)")
    s_show.add_argument("suite")
    s_show.add_argument("--out", required=True, help="PNG file")
    s_show.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    s_show.add_argument("--init", type=INDEX, default=0, help="init state index of the frames")
    s_gen = suites_sub.add_parser("generate", help="(re)write a derived suite's BDDL files and init states")
    s_gen.add_argument("suite")
    s_gen.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    s_gen.add_argument("--n", type=COUNT, default=50, help="init states per task")
    s_gen.add_argument("--force", action="store_true", help="regenerate init states that are already current")
    s_chk = suites_sub.add_parser("check", help="build each task's world, render its first frame, check its data")
    s_chk.add_argument("suite")
    s_chk.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    s_chk.add_argument("--inits", type=COUNT, default=5, help="init states per task to check (spread over all)")
    suites.set_defaults(func=_cmd_suites)


def _cmd_suites(args) -> int:
    from seal import suite_tools

    return suite_tools.main(args)
