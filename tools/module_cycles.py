#!/usr/bin/env python3
"""Import cycles between the top-level modules of a Rust crate's src/.

Usage: module_cycles.py SRC_DIR

A module uses another when a file of its subtree names `crate::<other>` in
code (comments, strings, `#[cfg(test)]` items and tests.rs / *_tests.rs files
ignored; `crate::Name` of a root re-export counts as its module). Prints the
edges, the strongly connected components of more than one module and the
number of elementary cycles.
"""
import os
import re
import sys


def code_only(text):
    out, i, n = [], 0, len(text)
    while i < n:
        r = text[i:]
        if r.startswith('//'):
            e = r.find('\n'); e = len(r) if e < 0 else e
        elif r.startswith('/*'):
            e = r.find('*/'); e = len(r) if e < 0 else e + 2
        elif re.match(r'r#*"', r):
            h = len(re.match(r'r(#*)"', r).group(1))
            close = '"' + '#' * h
            e = r.find(close, 2 + h); e = len(r) if e < 0 else e + len(close)
        elif r.startswith('"'):
            e, esc = len(r), False
            for j in range(1, len(r)):
                c = r[j]
                if c == '\\' and not esc: esc = True; continue
                if c == '"' and not esc: e = j + 1; break
                esc = False
        elif r.startswith("'") and (r[1:2] == '\\' or r[2:3] == "'"):
            e = r.find("'", 2 if r[1:2] == '\\' else 1); e = len(r) if e < 0 else e + 1
        else:
            out.append(r[0]); i += 1; continue
        out.append(re.sub(r'[^\n]', ' ', r[:e])); i += e
    return ''.join(out)


def without_test_items(code):
    while True:
        at = code.find('#[cfg(test)]')
        if at < 0:
            return code
        body = code[at:]
        semi, brace = body.find(';'), body.find('{')
        if semi >= 0 and (brace < 0 or semi < brace):
            end = semi + 1
        elif brace >= 0:
            depth, end = 0, len(body)
            for j in range(brace, len(body)):
                if body[j] == '{': depth += 1
                elif body[j] == '}':
                    depth -= 1
                    if depth == 0: end = j + 1; break
        else:
            end = len(body)
        code = code[:at] + re.sub(r'[^\n]', ' ', body[:end]) + code[at + end:]


def crate_paths(code):
    names = []
    for m in re.finditer(r'(?<![\w])crate::(\{|\w+)', code):
        if m.group(1) != '{':
            names.append(m.group(1)); continue
        depth, start, j = 0, True, m.end()
        while j < len(code):
            c = code[j]
            if c == '{': depth += 1
            elif c == '}':
                if depth == 0: break
                depth -= 1
            elif c == ',' and depth == 0: start = True
            elif start and (c.isalnum() or c == '_'):
                names.append(re.match(r'\w+', code[j:]).group(0)); start = False
            j += 1
    return names


def main(src):
    lib = code_only(open(os.path.join(src, 'lib.rs')).read())
    modules = set(re.findall(r'^\s*(?:pub )?mod (\w+);', lib, re.M))
    reexp = {}
    for stmt in lib.split(';'):
        m = re.match(r'\s*pub use (\w+)(.*)', stmt, re.S)
        if not m: continue
        names = m.group(2)
        names = names[names.find('{') + 1:] if '{' in names else names.rsplit('::', 1)[-1]
        for n in re.split(r'[,{}]', names):
            n = n.strip().rsplit('::', 1)[-1]
            if n and n != 'self': reexp[n] = m.group(1)
    edges = {m: set() for m in modules}
    for root, _, files in os.walk(src):
        for f in files:
            if not f.endswith('.rs') or f == 'tests.rs' or f.endswith('_tests.rs'): continue
            rel = os.path.relpath(os.path.join(root, f), src)
            if rel == 'lib.rs': continue
            mod = rel.split(os.sep)[0].removesuffix('.rs')
            code = without_test_items(code_only(open(os.path.join(root, f)).read()))
            for n in crate_paths(code):
                t = n if n in modules else reexp.get(n)
                if t and t != mod: edges[mod].add(t)
    # Tarjan's strongly connected components.
    index, low, stack, on, sccs, k = {}, {}, [], set(), [], [0]
    def visit(v):
        index[v] = low[v] = k[0]; k[0] += 1; stack.append(v); on.add(v)
        for w in sorted(edges[v]):
            if w not in index: visit(w); low[v] = min(low[v], low[w])
            elif w in on: low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            c = []
            while True:
                w = stack.pop(); on.discard(w); c.append(w)
                if w == v: break
            sccs.append(sorted(c))
    sys.setrecursionlimit(10000)
    for v in sorted(modules):
        if v not in index: visit(v)
    # Elementary cycles (each counted once, from its smallest module).
    cycles = []
    def walk(start, v, path):
        for w in sorted(edges[v]):
            if w == start: cycles.append(path + [start])
            elif w > start and w not in path: walk(start, w, path + [w])
    for s in sorted(modules): walk(s, s, [s])
    for m in sorted(modules):
        print(f'{m} -> {", ".join(sorted(edges[m])) or "-"}')
    cyc = [c for c in sccs if len(c) > 1]
    print(f'\nmodules: {len(modules)}; strongly connected groups of more than one module: {len(cyc)}')
    for c in cyc: print('  ' + ', '.join(c))
    print(f'elementary cycles: {len(cycles)}; two-module cycles: {sum(1 for c in cycles if len(c) == 3)}')
    for c in cycles[:40]: print('  ' + ' -> '.join(c))


if __name__ == '__main__':
    main(sys.argv[1])
