#!/usr/bin/env python3
"""
Mechanical fixes toward ament's flake8 and pep257 rules (tests/test_lint.py), file by file.

Usage: ``python tools/lint_fix.py FILE...`` (then ``python -m pytest -q tests/test_lint.py``).

What it does, in order: single quotes (Q000/Q003, Q001); google import order of the module-level
import runs without comments in them (I100/I101/I201); multi-line docstrings in ament's shape
(summary on the line after the quotes, D213; closing quotes alone, D209; a one-line summary ending
in a period when the first sentence, or the text before its first ``:``/``;``/``—``, fits one
line, D205/D400); docstring paragraphs re-filled at 99 columns; long code lines broken at the
outermost comma that fits, a trailing comment moved above (E501). A file whose code (docstrings
blanked, imports sorted) would change is left as it was. What it cannot do is listed: summaries
to write by hand, long lines to reshape, and everything else flake8/pydocstyle report (imperative
mood, ``dict()`` literals, ...). Read the diff: the summaries it splits off are mechanical.
"""
import ast
import io
import re
import sys
import textwrap
import tokenize

W = 99
STD = set(sys.stdlib_module_names)


def _norm(src):
    t = ast.parse(src)
    for n in ast.walk(t):
        if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            if (n.body and isinstance(n.body[0], ast.Expr)
                    and isinstance(n.body[0].value, ast.Constant)
                    and isinstance(n.body[0].value.value, str)):
                n.body[0].value.value = ''
        if isinstance(n, ast.ImportFrom):
            n.names.sort(key=lambda a: (a.name, a.asname or ''))
    imps = sorted(ast.dump(s) for s in t.body if isinstance(s, (ast.Import, ast.ImportFrom)))
    rest = [ast.dump(s) for s in t.body if not isinstance(s, (ast.Import, ast.ImportFrom))]
    return imps, rest


def ends_ok(s):
    return s.endswith(('.', '?', '!'))


def add_period(s):
    if re.search(r'[\w)`\]\'"]$', s):
        return s + '.'
    return None


ABBREVIATIONS = re.compile(
    r'(\be\.g|\bi\.e|\beq|\bch|\bvs|\betc|\bcf|\bFig|\bSec|\bapprox|\bno|\bp|\bseq|\bEq|\bTab)\.$')


def first_sentence(text, maxlen):
    """Split text at the end of its first sentence if that fits maxlen: (sentence, rest)."""
    for m in re.finditer(r'[.?!](\s+|$)', text):
        end = m.start() + 1
        sent = text[:end]
        if ABBREVIATIONS.search(sent):
            continue
        if re.search(r'\d\.$', sent) and end < len(text) and text[end:end + 1] != ' ':
            continue
        if len(sent) <= maxlen:
            return sent, text[m.end():].strip()
        return None
    return None


def clause_split(text, maxlen):
    """Split at the first ': ', '; ' or ' — ' outside brackets and code, if the head fits."""
    for sep in (': ', '; ', ' — '):
        depth, code = 0, False
        for i, ch in enumerate(text):
            if text.startswith('``', i):
                code = not code
            if text.startswith(sep, i) and depth == 0 and not code:
                if 15 <= i and i + 1 <= maxlen:
                    summary = text[:i].rstrip(',') + '.'
                    rest = text[i + len(sep):]
                    m = re.match(r'([a-z][a-z-]*)(\s)', rest)
                    if m and m.group(1) not in ('e', 'i'):
                        rest = rest[0].upper() + rest[1:]
                    return summary, rest
                break
            if ch in '([{':
                depth += 1
            elif ch in ')]}':
                depth = max(0, depth - 1)
    return None


def _summary_split(para, text, indent, ind):
    """Return (summary, tail lines) of a first paragraph of several lines, or a reason."""
    whole = first_sentence(text, 10 ** 6)
    if ends_ok(para[0]) and whole and whole[0] == para[0]:
        return para[0], [ind + p for p in para[1:]]
    fs = first_sentence(text, W - indent) or clause_split(text, W - indent)
    if not fs:
        return None, 'long first sentence: ' + text[:80]
    summary, tail = fs
    tail_lines = textwrap.wrap(tail, W - indent, initial_indent=ind, subsequent_indent=ind,
                               break_long_words=False, break_on_hyphens=False) if tail else []
    return summary, tail_lines


def fix_doc(raw, indent):
    """Return (the docstring in ament's shape, None) or (raw, why it needs a hand)."""
    m = re.match(r'([rRuU]?)("""|\'\'\')(.*)\2$', raw, re.S)
    if not m:
        return raw, 'not triple-quoted'
    pre, _, body = m.groups()
    q = '"""'
    ind = ' ' * indent
    if '\n' not in body:
        s = body.strip()
        if s and not ends_ok(s):
            if add_period(s) is None:
                return raw, 'summary without a period: ' + s
            s = add_period(s)
        new = f'{pre}{q}{s}{q}'
        if indent + len(new) > W:
            new = f'{pre}{q}\n{ind}{s}\n{ind}{q}'
        return new, None
    lines = body.split('\n')
    rest = [x.rstrip() for x in lines[1:]]
    if rest[-1].strip():
        rest.append('')
    content = ([ind + lines[0].strip()] if lines[0].strip() else []) + rest[:-1]
    while content and not content[0].strip():
        content.pop(0)
    k = 0
    while k < len(content) and content[k].strip():
        k += 1
    para = [c.strip() for c in content[:k]]
    after = content[k:]
    if (any(p.startswith(('-', '*', ':', '>>>', '|')) or p.endswith('::') for p in para[1:])
            or (para and para[0].startswith(('-', '*', ':', '>>>')))):
        return raw, 'structured first paragraph'
    tail_lines = []
    if len(para) == 1:
        summary = para[0]
        if not ends_ok(summary):
            if summary.endswith(':') or add_period(summary) is None:
                return raw, 'summary without a period: ' + summary
            summary = add_period(summary)
    else:
        summary, tail_lines = _summary_split(para, ' '.join(para), indent, ind)
        if summary is None:
            return raw, tail_lines
        if len(ind + summary) > W:
            return raw, 'summary too long'
    if not after and not tail_lines:
        one = f'{pre}{q}{summary}{q}'
        if indent + len(one) <= W:
            return one, None
    out = [ind + summary] + ([''] + tail_lines if tail_lines else []) + after
    while out and not out[-1].strip():
        out.pop()
    body_lines = '\n'.join(x if x.strip() else '' for x in out)
    return f'{pre}{q}\n{body_lines}\n{ind}{q}', None


def scan(s):
    """Per character of the code part: (inside a string, columns of the open brackets)."""
    info, stack, q, i = [], [], None, 0
    while i < len(s):
        ch = s[i]
        if q:
            info.append((True, list(stack)))
            if ch == '\\':
                info.append((True, list(stack)))
                i += 2
            elif s.startswith(q, i):
                info.extend([(True, list(stack))] * (len(q) - 1))
                i += len(q)
                q = None
            else:
                i += 1
            continue
        if ch == '#':
            break
        if ch in '"\'':
            q = s[i:i + 3] if s[i:i + 3] in ('"' * 3, "'" * 3) else ch
            info.extend([(True, list(stack))] * len(q))
            i += len(q)
            continue
        if ch in '([{':
            stack.append(i)
        elif ch in ')]}' and stack:
            stack.pop()
        info.append((False, list(stack)))
        i += 1
    return info


def _wrap_comment(s, ind):
    out, cur = [], ' ' * ind + '#'
    for word in s.strip()[1:].strip().split(' '):
        if len(cur) + 1 + len(word) > W:
            out.append(cur)
            cur = ' ' * ind + '#'
        cur += ' ' + word
    return out + [cur]


def _split_string(s, info, ind, in_bracket):
    m = None
    for mm in re.finditer(r"(?<![\w'\"])([fr]?)'([^'\\]*)'", s):
        if mm.start() < W < mm.end():
            m = mm
    if not m:
        return None
    stack = info[m.start()][1]
    col = stack[-1] + 1 if stack else (ind if in_bracket else None)
    if col is None:
        return None
    pre, body = m.group(1), m.group(2)
    start = m.start() + len(pre) + 1
    mid = (start + m.end() - 1) / 2
    spaces = sorted((j for j in range(start, W - 1) if s[j] == ' '), key=lambda j: abs(j - mid))
    if not spaces or spaces[0] <= start:
        return None
    k = spaces[0] + 1 - start
    if 'f' in pre and body[:k].count('{') != body[:k].count('}'):
        return None
    a = s[:m.start()] + f"{pre}'{body[:k]}'"
    b = ' ' * col + f"{pre}'{body[k:]}'" + s[m.end():]
    return [a, b] if len(a) <= W and len(b) <= W else None


def wrap_line(s, in_bracket):
    """Return the lines replacing the too long line ``s``, or None."""
    ind = len(s) - len(s.lstrip())
    info = scan(s)
    if len(info) < len(s) and s[:len(info)].strip():        # a trailing comment goes above
        code = s[:len(info)].rstrip()
        return [' ' * ind + s[len(info):].strip(), code] if len(code) <= W else None
    if s.strip().startswith('#'):
        return _wrap_comment(s, ind)
    cands = []
    for i in range(min(len(s), W) - 1, ind, -1):
        if s[i] == ',' and i + 1 < len(s) and s[i + 1] == ' ' and not info[i][0]:
            stack = info[i][1]
            if stack or in_bracket:
                cands.append((len(stack), -i, i, stack[-1] + 1 if stack else ind))
    for _, _, i, col in sorted(cands):          # the outermost comma that fits, rightmost first
        rest = ' ' * col + s[i + 2:]
        if len(rest) <= W:
            return [s[:i + 1], rest]
        sub = wrap_line(rest, True)
        if sub:
            return [s[:i + 1]] + sub
    return _split_string(s, info, ind, in_bracket)


def _docstrings(tree):
    for n in ast.walk(tree):
        if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            if (n.body and isinstance(n.body[0], ast.Expr)
                    and isinstance(n.body[0].value, ast.Constant)
                    and isinstance(n.body[0].value.value, str)):
                yield n.body[0]


def _requote(tok):
    m = re.match(r'([rRbBuUfF]*)(\'\'\'|"""|\'|")(.*)\2$', tok, re.S)
    if not m:
        return tok
    pre, q, body = m.groups()
    if q == '"' and "'" not in body and '\\"' not in body:
        return f"{pre}'{body}'"
    if q == "'" and "\\'" in body and '"' not in body and 'r' not in pre.lower():
        return pre + '"' + body.replace("\\'", "'") + '"'
    if q == "'" * 3 and '"' * 3 not in body and not body.endswith('"'):
        return pre + '"' * 3 + body + '"' * 3
    return tok


def fix_quotes(src, notes):
    docs = {(e.lineno, e.col_offset) for e in _docstrings(ast.parse(src))}
    edits = []
    for t in tokenize.generate_tokens(io.StringIO(src).readline):
        if t.type == tokenize.STRING and t.start not in docs:
            new = _requote(t.string)
            if new != t.string:
                edits.append((t.start, t.end, new))
    offs = [0]
    for line in src.splitlines(keepends=True):
        offs.append(offs[-1] + len(line))
    for (sl, sc), (el, ec), new in reversed(edits):
        src = src[:offs[sl - 1] + sc] + new + src[offs[el - 1] + ec:]
    return src


def _kind(s):
    if isinstance(s, ast.ImportFrom):
        if s.level:
            return 4
        top = s.module.split('.')[0]
    else:
        top = s.names[0].name.split('.')[0]
    if top == '__future__':
        return 0
    return 1 if top in STD else 2


def _nk(n):
    return (n.lower(), n)


def _ikey(s):
    if isinstance(s, ast.ImportFrom):
        return (_kind(s), s.level, [_nk(s.module or '')], [_nk(a.name) for a in s.names])
    return (_kind(s), 0, [_nk(a.name) for a in s.names], [])


def _render(s, text):
    if isinstance(s, ast.Import):
        return text
    names = sorted(s.names, key=lambda a: _nk(a.name))
    if [a.name for a in names] == [a.name for a in s.names]:
        return text
    alias = [a.name + (f' as {a.asname}' if a.asname else '') for a in names]
    head = 'from ' + '.' * s.level + (s.module or '') + ' import '
    if len(head + ', '.join(alias)) <= W:
        return head + ', '.join(alias)
    lines, cur = [], head + '('
    pad = ' ' * len(cur)
    for k, name in enumerate(alias):
        piece = name + (', ' if k < len(alias) - 1 else ')')
        if len(cur) + len(piece.rstrip()) > W:
            lines.append(cur.rstrip())
            cur = pad
        cur += piece
    return '\n'.join(lines + [cur])


def fix_imports(src, notes):
    lines = src.split('\n')
    runs, cur = [], []
    for s in ast.parse(src).body:
        if isinstance(s, (ast.Import, ast.ImportFrom)):
            cur.append(s)
        elif cur:
            runs.append(cur)
            cur = []
    if cur:
        runs.append(cur)
    for run in reversed(runs):
        a, b = run[0].lineno - 1, run[-1].end_lineno
        covered = {i for s in run for i in range(s.lineno - 1, s.end_lineno)}
        if (any(lines[i].strip() and i not in covered for i in range(a, b))
                or any(';' in lines[i] or '#' in lines[i] for i in covered)):
            notes.append(f'{a + 1}: imports with comments: order them by hand')
            continue
        texts = {id(s): '\n'.join(lines[s.lineno - 1:s.end_lineno]) for s in run}
        out, last = [], None
        for s in sorted(run, key=_ikey):
            if last is not None and _kind(s) != last:
                out.append('')
            out.append(_render(s, texts[id(s)]))
            last = _kind(s)
        lines[a:b] = '\n'.join(out).split('\n')
    return '\n'.join(lines)


def fix_docstrings(src, notes):
    raw_src = src.encode()
    offs = [0]
    for line in raw_src.splitlines(keepends=True):
        offs.append(offs[-1] + len(line))
    edits = []
    for e in _docstrings(ast.parse(raw_src)):
        a = offs[e.lineno - 1] + e.col_offset
        b = offs[e.end_lineno - 1] + e.end_col_offset
        raw = raw_src[a:b].decode()
        new, why = fix_doc(raw, e.col_offset)
        if why:
            notes.append(f'{e.lineno}: docstring: {why}')
        elif new != raw:
            edits.append((a, b, new.encode()))
    for a, b, new in sorted(edits, reverse=True):
        raw_src = raw_src[:a] + new + raw_src[b:]
    return raw_src.decode()


def refill_docstrings(src, notes):
    lines = src.split('\n')
    spans = [(e.lineno, e.end_lineno) for e in _docstrings(ast.parse(src))
             if e.end_lineno > e.lineno and lines[e.lineno - 1].strip() in ('"""', 'r"""')]
    for a, b in sorted(spans, reverse=True):
        paras, cur = [], []
        for i in range(a, b - 1):
            if lines[i].strip():
                cur.append(i)
            elif cur:
                paras.append(cur)
                cur = []
        if cur:
            paras.append(cur)
        for p in reversed(paras):
            if not any(len(lines[i]) > W for i in p):
                continue
            ind = [len(lines[i]) - len(lines[i].lstrip()) for i in p]
            m = re.match(r'([-*]|\d+\.|\(\w\))\s+', lines[p[0]].strip())
            hang = ind[0] + (len(m.group(0)) if m else 0)
            text = ' '.join(lines[i].strip() for i in p)
            if (not (all(x == hang for x in ind[1:]) or len(p) == 1) or '::' in text
                    or '>>>' in text
                    or any(lines[i].strip().startswith(('-', '*', '|')) for i in p[1:])):
                notes.append(f'{p[0] + 1}: long docstring line in a structured paragraph')
                continue
            new = textwrap.wrap(text, W, initial_indent=' ' * ind[0],
                                subsequent_indent=' ' * hang, break_long_words=False,
                                break_on_hyphens=False)
            if any(len(x) > W for x in new):
                notes.append(f'{p[0] + 1}: docstring word longer than a line')
                continue
            lines[p[0]:p[-1] + 1] = new
    return '\n'.join(lines)


def wrap_code(src, notes):
    lines = src.split('\n')
    depth_at, strings, d, cur = {}, set(), 0, 0
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        for ln in range(cur + 1, tok.start[0] + 1):
            depth_at.setdefault(ln, d)
        cur = tok.start[0]
        if tok.type == tokenize.OP and tok.string in '([{':
            d += 1
        elif tok.type == tokenize.OP and tok.string in ')]}':
            d -= 1
        elif tok.type == tokenize.STRING and tok.end[0] > tok.start[0]:
            strings.update(range(tok.start[0] + 1, tok.end[0] + 1))
    for ln in range(len(lines), 0, -1):
        if len(lines[ln - 1]) <= W or ln in strings:
            continue
        new = wrap_line(lines[ln - 1], depth_at.get(ln, 0) > 0)
        if new:
            lines[ln - 1:ln] = new
        else:
            notes.append(f'{ln}: line too long: reshape it by hand')
    return '\n'.join(lines)


def main(paths):
    if not paths or paths[0] in ('-h', '--help'):
        print('usage: python tools/lint_fix.py FILE...  (fixes toward tests/test_lint.py)')
        sys.exit(0 if paths else 2)
    for path in paths:
        try:
            with open(path, encoding='utf-8') as f:
                src = f.read()
        except OSError as exc:
            sys.exit(f'lint_fix: cannot read {path}: {exc.strerror}')
        new, notes = src, []
        for step in (fix_quotes, fix_imports, fix_docstrings, refill_docstrings, wrap_code):
            try:
                cand = step(new, notes)
                if _norm(cand) == _norm(new):
                    new = cand
                else:
                    notes.append(f'0: {step.__name__} would change the code: skipped')
            except SyntaxError as exc:
                notes.append(f'0: {step.__name__} broke the syntax ({exc}): skipped')
        if new != src:
            with open(path, 'w', encoding='utf-8') as f:
                f.write(new)
        for n in notes:
            print(f'{path}:{n}')


if __name__ == '__main__':
    main(sys.argv[1:])
