"""`furuta-rt repair`: rewrite a log left by a killed run (no summary, torn end) with a summary."""

from __future__ import annotations

import argparse

from rich.console import Console

from furuta_rt.io.repair import repair_log


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "repair",
        help="rewrite an MCAP log that was not closed (killed run) with a summary",
        description="Copy every complete chunk of LOG (messages untouched), its metadata and attachments into a "
        "complete MCAP file with indexes and a summary. Without -o (or with -o LOG) the log is rewritten in place "
        "and the original kept as LOG.bak (an existing LOG.bak only with --force). Nothing is replaced or deleted "
        "unless the rewrite succeeded.",
    )
    p.add_argument("log", metavar="LOG.mcap")
    p.add_argument("-o", "--output", metavar="OUT.mcap", default=None,
                   help="write here instead of in place (an existing file only with --force)")
    p.add_argument("--no-backup", action="store_true", help="in place: do not keep the original as LOG.bak")
    p.add_argument("--force", action="store_true",
                   help="rewrite even a log that was closed properly; replace an existing -o file or LOG.bak "
                   "(without it an existing one is refused, exit 2, before any work)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    con = Console(soft_wrap=True)
    r = repair_log(args.log, args.output, backup=not args.no_backup, force=args.force)
    if r.was_complete and not args.force and r.messages == 0:
        con.print(f"{r.source} was closed properly (it has a summary); nothing to repair", highlight=False)
        return 0
    con.print(f"wrote {r.output}: {r.messages} messages from {r.chunks} complete chunks, {r.span_s:.2f} s", highlight=False)
    if r.damaged_chunks:
        con.print(f"dropped {r.damaged_chunks} damaged chunk(s)", highlight=False)
    if r.dropped_bytes:
        con.print(f"dropped the last {r.dropped_bytes} bytes of {r.source} (an incomplete record)", highlight=False)
    if r.output == r.source and not args.no_backup:
        con.print(f"the original is kept as {r.source}.bak", highlight=False)
    return 0
