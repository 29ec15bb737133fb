/* The scattered paths' search of coordinator/lacam.py's `Scatter`, compiled (coordinator/compiled.py builds it with
   the system's C compiler and loads it through ctypes; where it cannot, `Scatter` runs its own Python). Step for step
   `Scatter._plan` and `Scatter._collisions`: the same cells settled in the same order, so the same paths and the same
   work units on every instance (tests/test_lacam.py checks both against each other). The queue is an indexed binary
   heap (one entry a cell, decreased when a lesser key is offered: the cells are popped in the order Python's lazy
   heapq pops each cell's least entry, the keys holding the cell so that no two are equal); the edges' counts an array
   by step, cell and direction. A context a `Scatter`: no global state. */

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct { int64_t c, f, v, g, p; } item; /* (collisions, length, cell, step, parent): Python's tuple */

typedef struct {
    int64_t F, N, K, longest, margin;
    const int64_t *near;  /* (F, K): each cell's open neighbours, -1 for none */
    const int16_t *dist;  /* (N, F): each drone's distance table */
    int32_t *occ;         /* (longest + 1, F): paths in a cell at a step */
    int32_t *edge;        /* (longest + 1, F, K): paths taking an edge, by step, cell and direction */
    int *opp;             /* (K): the direction back along each */
    int32_t **ends;       /* cell -> the steps from which paths ending there stay there, sorted */
    int32_t *ends_n, *ends_cap;
    int64_t **paths, *path_n;
    int64_t *parent;      /* (F): each settled cell's parent (-1: the start; -2: not settled) */
    item *heap;
    int64_t heap_n, heap_cap;
    int64_t *where;       /* (F): cell -> its entry's place in the heap, -1: none */
} ctx;

static int less(const item *a, const item *b) {
    if (a->c != b->c) return a->c < b->c;
    if (a->f != b->f) return a->f < b->f;
    if (a->v != b->v) return a->v < b->v;
    if (a->g != b->g) return a->g < b->g;
    return a->p < b->p;
}

static void place(ctx *s, int64_t i, item x) { s->heap[i] = x; s->where[x.v] = i; }

static void up_from(ctx *s, int64_t i, item x) {
    while (i > 0) {
        int64_t up = (i - 1) / 2;
        if (!less(&x, &s->heap[up])) break;
        place(s, i, s->heap[up]);
        i = up;
    }
    place(s, i, x);
}

static int offer(ctx *s, item x) {
    int64_t i = s->where[x.v];
    if (i >= 0) {
        if (less(&x, &s->heap[i])) up_from(s, i, x);
        return 1;
    }
    if (s->heap_n == s->heap_cap) {
        int64_t cap = s->heap_cap ? 2 * s->heap_cap : 1024;
        item *grown = realloc(s->heap, cap * sizeof(item));
        if (!grown) return 0;
        s->heap = grown;
        s->heap_cap = cap;
    }
    up_from(s, s->heap_n++, x);
    return 1;
}

static item pop(ctx *s) {
    item top = s->heap[0], x = s->heap[--s->heap_n];
    s->where[top.v] = -1;
    if (!s->heap_n) return top;
    int64_t i = 0;
    for (;;) {
        int64_t l = 2 * i + 1, r = l + 1, m = i;
        const item *best = &x;
        if (l < s->heap_n && less(&s->heap[l], best)) { m = l; best = &s->heap[l]; }
        if (r < s->heap_n && less(&s->heap[r], best)) { m = r; best = &s->heap[r]; }
        if (m == i) break;
        place(s, i, s->heap[m]);
        i = m;
    }
    place(s, i, x);
    return top;
}

static int dir_of(const ctx *s, int64_t a, int64_t b) {
    for (int k = 0; k < s->K; k++)
        if (s->near[a * s->K + k] == b) return k;
    return -1;
}

/* paths taking the edge from cell a at step t to its neighbour b (direction k from a, or -1: looked up) */
static int32_t moved(const ctx *s, int64_t t, int64_t a, int64_t b, int k) {
    return s->edge[(t * s->F + a) * s->K + (k >= 0 ? k : dir_of(s, a, b))];
}

static int64_t before_step(const ctx *s, int64_t u, int64_t t) { /* bisect_left */
    int64_t lo = 0, hi = s->ends_n[u];
    while (lo < hi) {
        int64_t m = (lo + hi) / 2;
        if (s->ends[u][m] < t) lo = m + 1; else hi = m;
    }
    return lo;
}

static int park(ctx *s, int64_t u, int32_t t, int sign) {
    int64_t k = before_step(s, u, t);
    if (sign > 0) {
        if (s->ends_n[u] == s->ends_cap[u]) {
            int32_t cap = s->ends_cap[u] ? 2 * s->ends_cap[u] : 4;
            int32_t *grown = realloc(s->ends[u], cap * sizeof(int32_t));
            if (!grown) return 0;
            s->ends[u] = grown;
            s->ends_cap[u] = cap;
        }
        memmove(s->ends[u] + k + 1, s->ends[u] + k, (s->ends_n[u] - k) * sizeof(int32_t));
        s->ends[u][k] = t;
        s->ends_n[u]++;
    } else {
        memmove(s->ends[u] + k, s->ends[u] + k + 1, (s->ends_n[u] - k - 1) * sizeof(int32_t));
        s->ends_n[u]--;
    }
    return 1;
}

static int enroll(ctx *s, int64_t i, int sign) {
    const int64_t *p = s->paths[i];
    int64_t n = s->path_n[i];
    for (int64_t t = 0; t < n; t++) {
        s->occ[t * s->F + p[t]] += sign;
        if (t + 1 < n) s->edge[(t * s->F + p[t]) * s->K + dir_of(s, p[t], p[t + 1])] += sign;
    }
    return n ? park(s, p[n - 1], (int32_t)(n - 1), sign) : 1;
}

void sc_free(ctx *s) {
    if (!s) return;
    if (s->paths) for (int64_t i = 0; i < s->N; i++) free(s->paths[i]);
    if (s->ends) for (int64_t u = 0; u < s->F; u++) free(s->ends[u]);
    free(s->occ); free(s->edge); free(s->opp); free(s->ends); free(s->ends_n); free(s->ends_cap);
    free(s->paths); free(s->path_n); free(s->parent); free(s->heap); free(s->where);
    free(s);
}

/* A context for `n` drones on `f` open cells (`near`: (f, k)), their distance tables `dist` ((n, f), kept by the
   caller while the context lives), paths of at most `longest` + 1 cells, `margin` steps longer than the shortest at
   most. NULL where memory is short. */
ctx *sc_new(int64_t f, int64_t n, int64_t k, int64_t longest, const int64_t *near, const int16_t *dist,
            int64_t margin) {
    ctx *s = calloc(1, sizeof(ctx));
    if (!s) return 0;
    s->F = f; s->N = n; s->K = k; s->longest = longest; s->margin = margin; s->near = near; s->dist = dist;
    s->occ = calloc((size_t)((longest + 1) * f), sizeof(int32_t));
    s->edge = calloc((size_t)((longest + 1) * f * k), sizeof(int32_t));
    s->opp = calloc((size_t)k, sizeof(int));
    s->ends = calloc((size_t)f, sizeof(int32_t *));
    s->ends_n = calloc((size_t)f, sizeof(int32_t));
    s->ends_cap = calloc((size_t)f, sizeof(int32_t));
    s->paths = calloc((size_t)(n ? n : 1), sizeof(int64_t *));
    s->path_n = calloc((size_t)(n ? n : 1), sizeof(int64_t));
    s->parent = malloc((size_t)(f ? f : 1) * sizeof(int64_t));
    s->where = malloc((size_t)(f ? f : 1) * sizeof(int64_t));
    if (!s->occ || !s->edge || !s->opp || !s->ends || !s->ends_n || !s->ends_cap || !s->paths || !s->path_n ||
        !s->parent || !s->where) {
        sc_free(s);
        return 0;
    }
    for (int64_t v = 0; v < f; v++) s->where[v] = -1;
    for (int d = 0; d < k; d++) {
        s->opp[d] = -1;
        for (int64_t v = 0; v < f && s->opp[d] < 0; v++)
            if (near[v * k + d] >= 0) s->opp[d] = dir_of(s, near[v * k + d], v);
    }
    return s;
}

/* `Scatter._plan`: drone i's path from `start` to `goal` planned again against the others'; the cells it settled
   (-1 where memory is short: its path is then none) */
int64_t sc_plan(ctx *s, int64_t i, int64_t start, int64_t goal) {
    if (s->path_n[i] && !enroll(s, i, -1)) return -1;
    const int16_t *d = s->dist + i * s->F;
    int64_t F = s->F, K = s->K, bound = d[start] + s->margin, settled = 0, met = -1;
    for (int64_t v = 0; v < F; v++) s->parent[v] = -2;
    s->heap_n = 0;
    if (!offer(s, (item){0, d[start], start, 0, -1})) return -1;
    while (s->heap_n) {
        item it = pop(s);
        int64_t v = it.v;
        if (s->parent[v] != -2) continue;
        s->parent[v] = it.p;
        settled++;
        if (v == goal) { met = it.c; break; }
        int64_t t = it.g + 1, tF = t * F, gF = it.g * F;
        for (int k = 0; k < K; k++) {
            int64_t u = s->near[v * K + k];
            if (u < 0 || s->parent[u] != -2 || t + d[u] > bound) continue;
            int64_t cc = it.c + s->occ[tF + u];
            if (s->occ[gF + u]) cc += moved(s, it.g, u, v, s->opp[k]);
            if (s->ends_n[u]) cc += before_step(s, u, t);
            if (!offer(s, (item){cc, t + d[u], u, t, v})) {
                for (int64_t w = 0; w < s->heap_n; w++) s->where[s->heap[w].v] = -1;
                s->heap_n = 0;
                return -1;
            }
        }
    }
    for (int64_t w = 0; w < s->heap_n; w++) s->where[s->heap[w].v] = -1; /* (the next search's heap is empty) */
    s->heap_n = 0;
    free(s->paths[i]);
    s->paths[i] = 0;
    s->path_n[i] = 0;
    if (met >= 0) {
        int64_t n = 0;
        for (int64_t v = goal; v >= 0; v = s->parent[v]) n++;
        s->paths[i] = malloc((size_t)n * sizeof(int64_t));
        if (!s->paths[i]) return -1;
        s->path_n[i] = n;
        for (int64_t v = goal, k = n; v >= 0; v = s->parent[v]) s->paths[i][--k] = v;
    }
    return enroll(s, i, 1) ? settled : -1;
}

/* `Scatter._collisions`: the paths' collisions with each other, each pair's counted from both sides */
int64_t sc_collisions(const ctx *s) {
    int64_t total = 0;
    for (int64_t i = 0; i < s->N; i++) {
        const int64_t *p = s->paths[i];
        for (int64_t t = 1; t < s->path_n[i]; t++) {
            int64_t v = p[t], u = p[t - 1];
            total += s->occ[t * s->F + v] - 1 + moved(s, t - 1, v, u, -1);
            if (s->ends_n[v]) total += before_step(s, v, t);
        }
    }
    return total;
}

int64_t sc_path_length(const ctx *s, int64_t i) { return s->path_n[i]; }

void sc_path_cells(const ctx *s, int64_t i, int64_t *out) {
    if (s->path_n[i]) memcpy(out, s->paths[i], (size_t)s->path_n[i] * sizeof(int64_t));
}

/* The exact search's joint moves (coordinator/exact.py's `Exact._successors`), compiled in the same library: every
   configuration one joint move from each of `rows` configurations `cfg` ((rows, n), numbered open cells), drone by
   drone each drone's moves (`moves`, (F, k): staying first, then the neighbours, -1 for none) in order, no two drones
   in a cell and none trading cells with another. Each is written as its code (the sum of cell x `powers`) and its
   source row, in the order Python's expansion makes them (source row by row, then the moves in order): Python then
   takes the first of each code alike. Returns how many, or -1 if they would pass `cap`. No state. */
static int64_t joint(int64_t n, int64_t k, const int64_t *moves, const int64_t *powers, const int64_t *from,
                     int64_t *nxt, int64_t i, int64_t code, int64_t src, int64_t *codes, int64_t *srcs, int64_t m,
                     int64_t cap) {
    if (i == n) {
        if (m >= cap) return -1;
        codes[m] = code;
        srcs[m] = src;
        return m + 1;
    }
    const int64_t *opt = moves + from[i] * k;
    for (int64_t c = 0; c < k; c++) {
        int64_t v = opt[c];
        if (v < 0) continue;
        int ok = 1;
        for (int64_t j = 0; j < i && ok; j++)
            if (nxt[j] == v || (nxt[j] == from[i] && v == from[j])) ok = 0;
        if (!ok) continue;
        nxt[i] = v;
        m = joint(n, k, moves, powers, from, nxt, i + 1, code + v * powers[i], src, codes, srcs, m, cap);
        if (m < 0) return -1;
    }
    return m;
}

int64_t ex_successors(int64_t rows, int64_t n, const int64_t *cfg, int64_t k, const int64_t *moves,
                      const int64_t *powers, int64_t *codes, int64_t *srcs, int64_t cap) {
    int64_t nxt[64];
    int64_t m = 0;
    if (n > 64) return -1;
    for (int64_t r = 0; r < rows; r++) {
        m = joint(n, k, moves, powers, cfg + r * n, nxt, 0, 0, r, codes, srcs, m, cap);
        if (m < 0) return -1;
    }
    return m;
}
