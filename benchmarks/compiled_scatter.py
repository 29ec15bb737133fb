"""The scattered paths' search compiled: `lacam.Scatter` against a C port of it, the same paths (issue 37).

    dronesim bench compiled-scatter [--families F,...] [--seeds 5] [--agents 400] [--repeat 3]

An experiment, not a mechanism: games run `lacam.Scatter`, in Python; its turn is the game's longest (docs/
cooperation.md, "Scattered paths"). This measures what a compiled one would give before anyone builds it. `SOURCE`
is `Scatter.advance` with an unbounded budget written again in C, step for step: the same best-first search (a
binary heap ordered as Python orders its tuples: collisions, length, cell, step, parent), the edges' counts in a
hash table (`moves`), the parked drones' end steps sorted per cell (`parked`), the rounds in the orders
`lacam.scatter_order` draws, stopped as `advance` stops them. It is compiled by the system's C compiler (`cc`) into a
temporary folder and called through ctypes. Each instance's paths must equal Python's, else exit 1. Times: process
CPU of the whole call (the C side's set-up included), Python and C alternated, the best of `--repeat`. The C port
twice: as Python's structures (its queue as heapq's: every entry pushed, a settled cell's later entries popped and
skipped; the edges' counts in a hash table) and tuned (an indexed heap: one entry a cell, decreased when a lesser key
is offered, the same cells popped in the same order; the edges' counts an array by step, cell and direction).
"""

from __future__ import annotations

import argparse
import ctypes
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.swarm import movingai_instance
from coordinator import lacam
from coordinator.arbiter import OpenCells
from world import movingai
from world.search import flat_cells

SOURCE = r"""
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct { int64_t c, f, v, g, p; } item;  /* (collisions, length, cell, step, parent), as Python's tuple */
static int less(const item *a, const item *b) {
    if (a->c != b->c) return a->c < b->c;
    if (a->f != b->f) return a->f < b->f;
    if (a->v != b->v) return a->v < b->v;
    if (a->g != b->g) return a->g < b->g;
    return a->p < b->p;
}
static item *heap; static int64_t heap_n, heap_cap;
#ifndef TUNED
/* the queue as Python's heapq holds it: every entry pushed, a cell's later (worse) entries popped and skipped */
static void place(int64_t i, item x) { heap[i] = x; }
static int64_t entry(int64_t v) { (void)v; return -1; }  /* (every offer a new entry) */
static void forget(int64_t f) { (void)f; }
static void taken(int64_t v) { (void)v; }
static void queue_close(void) {}
#else
/* an indexed heap: one entry a cell, its least key offered so far (decrease-key); a cell's entries are popped in the
   same order as the lazy heap's first entry of each cell (the keys hold the cell: no two cells' keys are equal) */
static int64_t *where, where_cap;  /* cell -> its entry's place in the heap, -1: none */
static void place(int64_t i, item x) { heap[i] = x; where[x.v] = i; }
static int64_t entry(int64_t v) { return where[v]; }
static void forget(int64_t f) {  /* a new search: no cell in the heap */
    if (where_cap < f) { where = realloc(where, f * 8); where_cap = f; }
    for (int64_t k = 0; k < f; k++) where[k] = -1;
}
static void taken(int64_t v) { where[v] = -1; }
static void queue_close(void) { free(where); where = 0; where_cap = 0; }
#endif
static void up_from(int64_t i, item x) {
    while (i > 0) { int64_t up = (i - 1) / 2; if (!less(&x, &heap[up])) break; place(i, heap[up]); i = up; }
    place(i, x);
}
static void offer(item x) {
    int64_t i = entry(x.v);
    if (i >= 0) { if (less(&x, &heap[i])) up_from(i, x); return; }
    if (heap_n == heap_cap) {
        heap_cap = heap_cap ? 2 * heap_cap : 1024;
        heap = realloc(heap, heap_cap * sizeof(item));
    }
    up_from(heap_n++, x);
}
static item pop(void) {
    item top = heap[0], x = heap[--heap_n];
    taken(top.v);
    if (!heap_n) return top;
    int64_t i = 0;
    for (;;) {
        int64_t l = 2 * i + 1, r = l + 1, m = i; const item *best = &x;
        if (l < heap_n && less(&heap[l], best)) { m = l; best = &heap[l]; }
        if (r < heap_n && less(&heap[r], best)) { m = r; best = &heap[r]; }
        if (m == i) break;
        place(i, heap[m]); i = m;
    }
    place(i, x);
    return top;
}

static int64_t F, N; static int32_t *occ; static const int64_t *near;

/* moves: paths taking the edge from cell a at step t to its neighbour b at t + 1 (`moved`, `move`) */
#ifndef TUNED
/* as Python's dict: (step, cell, next cell) -> the count (open addressing) */
typedef struct { int64_t key; int32_t count; } slot;
static slot *table; static int64_t table_cap, table_n;
static int64_t hashed(int64_t k) {  /* splitmix64's finaliser: every bit of the key in the low bits */
    uint64_t x = (uint64_t)k;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return (int64_t)((x ^ (x >> 31)) >> 1);
}
static int32_t moves_get(int64_t k) {
    for (int64_t i = hashed(k) & (table_cap - 1); table[i].key != -1; i = (i + 1) & (table_cap - 1))
        if (table[i].key == k) return table[i].count;
    return 0;
}
static void moves_add(int64_t k, int32_t d) {
    if (2 * (table_n + 1) > table_cap) {
        int64_t old_cap = table_cap; slot *old = table;
        table_cap = old_cap ? 2 * old_cap : 1 << 16; table_n = 0;
        table = malloc(table_cap * sizeof(slot));
        for (int64_t i = 0; i < table_cap; i++) table[i].key = -1;
        for (int64_t i = 0; i < old_cap; i++) if (old[i].key != -1) {
            int64_t j = hashed(old[i].key) & (table_cap - 1);
            while (table[j].key != -1) j = (j + 1) & (table_cap - 1);
            table[j] = old[i]; table_n++;
        }
        free(old);
    }
    int64_t i = hashed(k) & (table_cap - 1);
    for (; table[i].key != -1; i = (i + 1) & (table_cap - 1)) if (table[i].key == k) { table[i].count += d; return; }
    table[i].key = k; table[i].count = d; table_n++;
}
#define OPP(k) (-1)
static int32_t moved(int64_t t, int64_t a, int64_t b, int k) { (void)k; return moves_get((t * F + a) * F + b); }
static void move(int64_t t, int64_t a, int64_t b, int32_t d) { moves_add((t * F + a) * F + b, d); }
static void moves_open(int64_t longest) { (void)longest; table = 0; table_cap = 0; table_n = 0; moves_add(-2, 0); }
static void moves_close(void) { free(table); table = 0; }
#else
/* a count a (step, cell, direction): no hashing, no probing ((longest + 1) x F x 6 counts) */
static int32_t *edge; static int opp[6];  /* opp[k]: the direction back along direction k */
#define OPP(k) opp[k]
static int dir_of(int64_t a, int64_t b) { for (int k = 0; k < 6; k++) if (near[a * 6 + k] == b) return k; return -1; }
static int32_t moved(int64_t t, int64_t a, int64_t b, int k) {
    return edge[(t * F + a) * 6 + (k >= 0 ? k : dir_of(a, b))];
}
static void move(int64_t t, int64_t a, int64_t b, int32_t d) { edge[(t * F + a) * 6 + dir_of(a, b)] += d; }
static void moves_open(int64_t longest) {
    edge = calloc((longest + 1) * F * 6, 4);
    for (int k = 0; k < 6; k++) {
        opp[k] = -1;
        for (int64_t v = 0; v < F && opp[k] < 0; v++) if (near[v * 6 + k] >= 0) opp[k] = dir_of(near[v * 6 + k], v);
    }
}
static void moves_close(void) { free(edge); edge = 0; }
#endif

/* parked: cell -> the steps from which paths ending there stay there, sorted */
static int32_t **ends; static int32_t *ends_n, *ends_cap;
static int64_t before_step(int64_t u, int64_t t) {  /* bisect_left */
    int64_t lo = 0, hi = ends_n[u];
    while (lo < hi) { int64_t m = (lo + hi) / 2; if (ends[u][m] < t) lo = m + 1; else hi = m; }
    return lo;
}
static void park(int64_t u, int32_t t, int sign) {
    int64_t k = before_step(u, t);
    if (sign > 0) {
        if (ends_n[u] == ends_cap[u]) {
            ends_cap[u] = ends_cap[u] ? 2 * ends_cap[u] : 4;
            ends[u] = realloc(ends[u], ends_cap[u] * 4);
        }
        memmove(ends[u] + k + 1, ends[u] + k, (ends_n[u] - k) * 4); ends[u][k] = t; ends_n[u]++;
    } else {
        memmove(ends[u] + k, ends[u] + k + 1, (ends_n[u] - k - 1) * 4); ends_n[u]--;
    }
}

static int64_t **paths, *path_n, *parent;

static void enroll(int64_t i, int sign) {
    const int64_t *p = paths[i]; int64_t n = path_n[i];
    for (int64_t t = 0; t < n; t++) {
        occ[t * F + p[t]] += sign;
        if (t + 1 < n) move(t, p[t], p[t + 1], sign);
    }
    if (n) park(p[n - 1], (int32_t)(n - 1), sign);
}

static int64_t plan(int64_t i, int64_t s, int64_t goal, const int16_t *d, int64_t margin) {
    if (path_n[i]) enroll(i, -1);
    int64_t bound = d[s] + margin, settled = 0, met = -1;
    for (int64_t k = 0; k < F; k++) parent[k] = -2;
    heap_n = 0; forget(F);
    offer((item){0, d[s], s, 0, -1});
    while (heap_n) {
        item it = pop();
        int64_t v = it.v;
        if (parent[v] != -2) continue;
        parent[v] = it.p; settled++;
        if (v == goal) { met = it.c; break; }
        int64_t t = it.g + 1, tF = t * F, gF = it.g * F;
        for (int k = 0; k < 6; k++) {
            int64_t u = near[v * 6 + k];
            if (u < 0 || parent[u] != -2 || t + d[u] > bound) continue;
            int64_t cc = it.c + occ[tF + u];
            if (occ[gF + u]) cc += moved(it.g, u, v, OPP(k));
            if (ends_n[u]) cc += before_step(u, t);
            offer((item){cc, t + d[u], u, t, v});
        }
    }
    free(paths[i]); paths[i] = 0; path_n[i] = 0;
    if (met >= 0) {
        int64_t n = 0;
        for (int64_t v = goal; v >= 0; v = parent[v]) n++;
        paths[i] = malloc(n * 8); path_n[i] = n;
        for (int64_t v = goal, k = n; v >= 0; v = parent[v]) paths[i][--k] = v;
    }
    enroll(i, 1);
    return settled;
}

static int64_t collisions(void) {
    int64_t total = 0;
    for (int64_t i = 0; i < N; i++) {
        const int64_t *p = paths[i];
        for (int64_t t = 1; t < path_n[i]; t++) {
            int64_t v = p[t], u = p[t - 1];
            total += occ[t * F + v] - 1 + moved(t - 1, v, u, -1);
            if (ends_n[v]) total += before_step(v, t);
        }
    }
    return total;
}

/* Scatter(...).advance(unbounded): the rounds run (`orders`: rounds x n drones); the cells settled in `settled`, the
   work units spent in `units` (advance's: a unit a path and one per `pops` cells it settled, n a round's count) */
int64_t scatter(int64_t f, int64_t n, int64_t longest, const int64_t *near_, const int64_t *start,
                const int64_t *goal, const int16_t *dist, int64_t margin, int64_t rounds, const int64_t *orders,
                int64_t pops, int64_t *settled, int64_t *units) {
    F = f; N = n; near = near_;
    occ = calloc((longest + 1) * f, 4); paths = calloc(n, sizeof(int64_t *)); path_n = calloc(n, 8);
    parent = malloc(f * 8); ends = calloc(f, sizeof(int32_t *)); ends_n = calloc(f, 4); ends_cap = calloc(f, 4);
    moves_open(longest);
    int64_t last = -1, r = 0; *settled = 0; *units = 0;
    for (;;) {
        for (int64_t k = 0; k < n; k++) {
            int64_t i = orders[r * n + k], cells = plan(i, start[i], goal[i], dist + i * f, margin);
            *settled += cells; *units += 1 + cells / pops;
        }
        int64_t total = collisions(); r++; *units += n;
        if (total == 0 || r >= rounds || (r >= 2 && total >= last)) break;
        last = total;
    }
    return r;
}

int64_t path_length(int64_t i) { return path_n[i]; }
void path_cells(int64_t i, int64_t *out) { memcpy(out, paths[i], path_n[i] * 8); }
void release(void) {
    for (int64_t i = 0; i < N; i++) free(paths[i]);
    for (int64_t u = 0; u < F; u++) free(ends[u]);
    free(occ); free(paths); free(path_n); free(parent); free(ends); free(ends_n); free(ends_cap);
    moves_close(); queue_close(); free(heap);
    heap = 0; heap_n = heap_cap = 0;
}
"""


def compiled(folder: Path, tuned: bool = False) -> ctypes.CDLL:
    """`SOURCE` compiled by the system's C compiler in `folder` (`tuned`: its queue an indexed heap, one entry a
    cell, not heapq's lazy one, and its edges' counts an array, not a hash table); RuntimeError if there is none or
    it fails."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise RuntimeError("no C compiler (cc, gcc) on the PATH")
    src, lib = folder / "scatter.c", folder / ("scatter-tuned.so" if tuned else "scatter.so")
    src.write_text(SOURCE)
    done = subprocess.run([cc, "-O2", "-shared", "-fPIC", *(["-DTUNED"] if tuned else []), "-o", str(lib),
                           str(src)], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{cc} failed: {done.stderr.strip()}")
    out = ctypes.CDLL(str(lib))
    i64, ptr = ctypes.c_int64, ctypes.c_void_p
    out.scatter.argtypes = [i64, i64, i64, ptr, ptr, ptr, ptr, i64, i64, ptr, i64, ptr, ptr]
    out.scatter.restype = i64
    out.path_length.argtypes, out.path_length.restype = [i64], i64
    out.path_cells.argtypes = [i64, ptr]
    return out


def c_paths(lib: ctypes.CDLL, graph: lacam.Graph, start: np.ndarray, goal: np.ndarray, dist: np.ndarray,
            margin: int = lacam.MARGIN, rounds: int = lacam.ROUNDS) -> tuple[list[list[int]], int, int, int]:
    """`lacam.Scatter(graph, start, goal, dist, margin, rounds)`'s paths once advanced to its end, made by `lib`;
    the rounds it ran, the cells it settled and the work units it spent (what `advance` returns)."""
    n, f = len(start), len(graph.cells)
    longest = int(dist[np.arange(n), start].max(initial=0)) + margin + 1
    near = np.ascontiguousarray(graph.near, np.int64)
    d16 = np.ascontiguousarray(dist, np.int16)
    orders = np.array([lacam.scatter_order(n, r) for r in range(rounds)], np.int64).reshape(rounds, n)
    s, g = np.ascontiguousarray(start, np.int64), np.ascontiguousarray(goal, np.int64)
    settled, units = ctypes.c_int64(), ctypes.c_int64()
    ran = lib.scatter(f, n, longest, near.ctypes.data, s.ctypes.data, g.ctypes.data, d16.ctypes.data, margin,
                      rounds, orders.ctypes.data, lacam.POPS, ctypes.byref(settled), ctypes.byref(units))
    paths = []
    for i in range(n):
        cells = np.zeros(lib.path_length(i), np.int64)
        lib.path_cells(i, cells.ctypes.data)
        paths.append(cells.tolist())
    lib.release()
    return paths, int(ran), settled.value, units.value


def instance(family: str, agents: int, seed: int) -> tuple[lacam.Graph, np.ndarray, np.ndarray, np.ndarray]:
    """A benchmark instance's graph, its drones' open cells and goals (numbered) and their distance tables."""
    inst = movingai_instance(family, agents, seed)
    size = inst.grid.shape
    arb = lacam.Lacam()
    arb.prepare(size, OpenCells(inst.grid))
    graph, every = arb._graph, arb._every
    assert graph is not None and every is not None
    start = graph.index[flat_cells(np.array(inst.starts, np.int32), size)]
    goal = graph.index[flat_cells(np.array(inst.goals, np.int32), size)]
    return graph, start, goal, every[goal]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim bench compiled-scatter", description=__doc__.split("\n")[0])
    p.add_argument("--families", default=",".join(movingai.FAMILIES))
    p.add_argument("--seeds", type=int, default=5, help="seeds 1..N of each family (default 5)")
    p.add_argument("--agents", type=int, default=400)
    p.add_argument("--repeat", type=int, default=3, help="the best of this many timings each (default 3)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="dronesim-scatter-") as tmp:
        plain, tuned = compiled(Path(tmp)), compiled(Path(tmp), tuned=True)
        print("| instance | rounds | cells settled | Python ms | C ms | C tuned ms | Python ÷ C | Python ÷ C tuned | "
              "the same paths |")
        print("|---|---|---|---|---|---|---|---|---|")
        differ = 0
        for family in [f for f in args.families.split(",") if f]:
            for seed in range(1, args.seeds + 1):
                graph, start, goal, dist = instance(family, args.agents, seed)
                py_ms: list[float] = []
                c_ms: list[float] = []
                ci_ms: list[float] = []
                same = True
                for _ in range(args.repeat):
                    t0 = time.process_time()
                    made = lacam.Scatter(graph, start, goal, dist)
                    spent = made.advance(1 << 62)
                    py_ms.append(1000 * (time.process_time() - t0))
                    for lib, ms in ((plain, c_ms), (tuned, ci_ms)):
                        t0 = time.process_time()
                        paths, ran, settled, units = c_paths(lib, graph, start, goal, dist)
                        ms.append(1000 * (time.process_time() - t0))
                        same = same and (paths, ran, units) == (made.paths, made.round, spent)
                differ += not same
                print(f"| {family} seed {seed}, {args.agents} drones | {ran} | {settled:,} | {min(py_ms):.0f} | "
                      f"{min(c_ms):.1f} | {min(ci_ms):.1f} | {min(py_ms) / min(c_ms):.1f} | "
                      f"{min(py_ms) / min(ci_ms):.1f} | {'yes' if same else 'NO'} |", flush=True)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
