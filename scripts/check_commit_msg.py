"""The commit-msg hook of .pre-commit-config.yaml: a subject of at most 72 characters, and the
details in a body after one blank line, so that `git log --oneline` and GitHub show whole
subjects.

    python scripts/check_commit_msg.py .git/COMMIT_EDITMSG
"""

from __future__ import annotations

import sys
from pathlib import Path

MAX_SUBJECT = 72
#: git's own line in `git commit -v`: everything below it is the diff, not the message.
SCISSORS = "# ------------------------ >8 ------------------------"
#: Subjects git writes itself (a merge of a long branch name, a revert of a 72-character
#: subject): not the author's to shorten.
GENERATED = ("Merge ", 'Revert "')


def message_lines(text: str) -> list[str]:
    """The message as git keeps it: above the scissors, without comment lines, no trailing
    blank lines."""
    lines = []
    for line in text.split(SCISSORS)[0].splitlines():
        if not line.startswith("#"):
            lines.append(line.rstrip())
    while lines and not lines[-1]:
        lines.pop()
    while lines and not lines[0]:
        lines.pop(0)
    return lines


def problems(text: str) -> list[str]:
    """What is wrong with a commit message; empty when it is fine."""
    lines = message_lines(text)
    if not lines:
        return ["the message is empty"]
    subject = lines[0]
    if subject.startswith(GENERATED):
        return []
    found = []
    if len(subject) > MAX_SUBJECT:
        found.append(
            f"the subject has {len(subject)} characters (at most {MAX_SUBJECT}): "
            "move the details into the body"
        )
    if len(lines) > 1 and lines[1]:
        found.append("the subject needs a blank line after it, before the body")
    return found


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        sys.stderr.write("usage: check_commit_msg.py MESSAGE_FILE\n")
        return 2
    found = problems(Path(argv[0]).read_text(encoding="utf-8"))
    for problem in found:
        sys.stderr.write(f"commit message: {problem}\n")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
