#!/usr/bin/env python3
"""Checks every relative link (and #anchor) of README.md and docs/*.md: run from the
repository root, `python3 scripts/check-doc-links.py`; exits 1 on a broken one."""
import re, sys, os, glob
os.chdir(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
def anchors(path):
    out = set()
    for line in open(path, encoding='utf-8'):
        m = re.match(r'^(#+)\s+(.*)', line)
        if m:
            t = m.group(2).strip().lower()
            t = re.sub(r'[^\w\- ]', '', t)  # GitHub: drop punctuation
            out.add(t.replace(' ', '-'))
    return out
bad = 0
files = ['README.md'] + sorted(glob.glob('docs/*.md'))
for f in files:
    text = open(f, encoding='utf-8').read()
    text = re.sub(r'```.*?```', '', text, flags=re.S)
    for m in re.finditer(r'\]\(([^)\s]+)\)', text):
        link = m.group(1)
        if re.match(r'[a-z]+:', link):
            continue
        target, _, anchor = link.partition('#')
        path = os.path.normpath(os.path.join(os.path.dirname(f), target)) if target else f
        if not os.path.exists(path):
            print(f'{f}: missing {link}'); bad += 1; continue
        if anchor and path.endswith('.md') and anchor not in anchors(path):
            print(f'{f}: no anchor {link}'); bad += 1
print(f'{len(files)} files, {bad} bad links'); sys.exit(1 if bad else 0)
