"""Comments and docstrings state rules, not history: no dates, no tracker references.

Scans the comments (tokenize) and docstrings (module, class, function) of every Python file
of the packages, the tests, the benchmarks and the scripts for a calendar date, an issue
number or item of the tracker, or a numbered CI run or session. The story of a change
belongs in its commit message; a comment says what the code does and why. String literals
that are data (a timestamp in a generated file) are not prose and are not scanned.
"""
from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

from suite_paths import PYTHON_PACKAGES, REPO_ROOT

ROOTS = (*PYTHON_PACKAGES, 'tests', 'benchmarks', 'scripts')
HISTORY = re.compile(
    r'\b20\d\d-[01]\d-[0-3]\d\b'                   # a calendar date
    r"|\bissues? (?:item )?\d+|\bissue item\b|\bthe issue's\b"   # the tracker
    r'|\bCI run \d+|\bsession \d+',                 # a numbered run of the past
    re.IGNORECASE)


def _python_files() -> list[Path]:
    return sorted(p for root in ROOTS for p in (REPO_ROOT / root).rglob('*.py')
                  if 'build' not in p.relative_to(REPO_ROOT).parts)


def _prose(source: str) -> list[tuple[int, str]]:
    """(line, text) of every comment and docstring of ``source``."""
    out = [(tok.start[0], tok.string)
           for tok in tokenize.generate_tokens(io.StringIO(source).readline)
           if tok.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                first = body[0].lineno
                out += [(first + k, line)
                        for k, line in enumerate(body[0].value.value.splitlines())]
    return out


def test_the_scan_finds_what_it_is_for() -> None:
    source = ('"""A module (issue 7)."""\n'
              'x = 1  # seen on 2026-11-25\n'
              'def f():\n    """Issue 13 item 2: a rule."""\n'
              "y = '2026-11-25'  # data, not prose\n")
    found = sorted(line for line, text in _prose(source) if HISTORY.search(text))
    assert found == [1, 2, 4]
    assert not HISTORY.search('issued 0.5 s ago; 95 % CI 4.5 %; a new publisher session')


def test_no_dates_or_issue_numbers_in_comments_and_docstrings() -> None:
    files = _python_files()
    assert len(files) > 100
    found = []
    for path in files:
        source = path.read_text(encoding='utf-8')
        if not HISTORY.search(source):      # most files: no need to tokenize them
            continue
        for line, text in _prose(source):
            if HISTORY.search(text):
                found.append(f'{path.relative_to(REPO_ROOT)}:{line}: {text.strip()}')
    assert not found, 'history in comments or docstrings (say the rule; the story belongs ' \
                      'in the commit message):\n' + '\n'.join(found)
