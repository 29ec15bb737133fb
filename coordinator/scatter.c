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

/* Every path at once: the cells of all (`sc_paths_length` of them) one after the other into `cells`, each one's length
   into `lengths` (N). */
int64_t sc_paths_length(const ctx *s) {
    int64_t total = 0;
    for (int64_t i = 0; i < s->N; i++) total += s->path_n[i];
    return total;
}

void sc_paths(const ctx *s, int64_t *lengths, int64_t *cells) {
    for (int64_t i = 0; i < s->N; i++) {
        lengths[i] = s->path_n[i];
        if (s->path_n[i]) memcpy(cells, s->paths[i], (size_t)s->path_n[i] * sizeof(int64_t));
        cells += s->path_n[i];
    }
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

/* PIBT's call over flat cells (coordinator/arbiter.py's `pibt`, with its `Corridors`, `_swapped`, `_reverse`, `_pull`
   and `_out_of_the_way`), compiled in the same library for the complete arbitration's search (coordinator/lacam.py's
   `Search._successor`): step for step Python's, the same cells tried in the same order, so the same next cells and the
   same drones that gave way (tests/test_lacam.py checks both against each other on random crowds). Python's dicts and
   sets are arrays over the flat cells made for the call (a drone's number + 1, 0 for none; a walk's cells marked with
   its stamp); the push chain a stack of frames, each with its own list of cells to try. No state. */

#define PB_MOST 16

typedef struct { int64_t i, len, k, pull; int64_t mine[PB_MOST]; } pb_frame;

typedef struct {
    int64_t n, W, C, S, Y, Z;
    const int64_t *here, *cand, *goal, *aim, *steps;
    const uint8_t *bits;  /* the open cells (NULL: no swap) */
    int64_t *nxt;
    int32_t *now, *claimed, *wr, *wb;  /* cell -> drone + 1; walks' stamps (`required`, `beyond`) */
    int32_t sr, sb;
} pb;

static int pb_open(const pb *p, int64_t u) { return u >= 0 && u < p->C && (p->bits[u >> 3] >> (u & 7) & 1); }
static int64_t pb_now(const pb *p, int64_t u) { return u >= 0 && u < p->C ? (int64_t)p->now[u] - 1 : -1; }
static int64_t pb_claimed(const pb *p, int64_t u) { return u >= 0 && u < p->C ? (int64_t)p->claimed[u] - 1 : -1; }

static int64_t pb_index(const int64_t *xs, int64_t n, int64_t x) {
    for (int64_t k = 0; k < n; k++)
        if (xs[k] == x) return k;
    return -1;
}

static int64_t pb_manhattan(const pb *p, int64_t u, int64_t v) {
    int64_t uz = u % p->Z, vz = v % p->Z, uxy = u / p->Z, vxy = v / p->Z;
    int64_t dx = uxy / p->Y - vxy / p->Y, dy = uxy % p->Y - vxy % p->Y, dz = uz - vz;
    return (dx < 0 ? -dx : dx) + (dy < 0 ? -dy : dy) + (dz < 0 ? -dz : dz);
}

static int pb_pocket(const pb *p, int64_t u) {  /* `Corridors._is_pocket` */
    int n = 0;
    for (int64_t s = 0; s < p->S; s++) n += pb_open(p, u + p->steps[s]);
    return n == 1;
}

static int pb_ways(const pb *p, int64_t v, int64_t back, int parked, int64_t out[2]) {  /* `Corridors.ways` */
    int m = 0;
    for (int64_t s = 0; s < p->S; s++) {
        int64_t u = v + p->steps[s];
        if (u == back || !pb_open(p, u)) continue;
        int64_t k = pb_now(p, u);
        if (k >= 0 && (!parked || p->goal[k] == u) && pb_pocket(p, u)) continue;
        out[m++] = u;
        if (m == 2) break;
    }
    return m;
}

static int pb_beyond(pb *p, int64_t a, int64_t b, int64_t g, int parked, int64_t dead) {  /* `Corridors.beyond` */
    int32_t st = ++p->sb;
    p->wb[b] = st;
    for (;;) {
        int64_t on[2];
        int m = pb_ways(p, b, a, parked, on);
        if (m != 1) return m >= 2;
        a = b;
        b = on[0];
        if (b == g) return 1;
        if (p->wb[b] == st || b == dead) return 0;
        p->wb[b] = st;
    }
}

static int pb_required(pb *p, int64_t i, int64_t j, int64_t vi, int64_t vj, int clear) {  /* `Corridors.required` */
    int64_t gi = p->goal[i], gj = p->goal[j], a = vi, b = vj, on[2];
    if (gj < 0) return 0;
    int32_t st = ++p->sr;
    p->wr[b] = st;
    while (a != gi) {
        int m = pb_ways(p, b, a, 1, on);
        if (m >= 2) return 0;
        if (m == 0) break;
        a = b;
        b = on[0];
        if (p->wr[b] == st || pb_now(p, b) >= 0) return 0;
        p->wr[b] = st;
    }
    if (clear) return (gi == a || gi == b) && gj != b && !pb_beyond(p, a, b, gj, 1, -1);
    if (gj == vj) return b != vj && !pb_beyond(p, a, b, gj, 1, -1);
    return gj != vi && p->wr[gj] != st;
}

static void pb_copy(pb_frame *f, const int64_t *mine, int64_t len) {
    memcpy(f->mine, mine, (size_t)len * sizeof(int64_t));
    f->len = len;
}

static void pb_reverse(pb_frame *f, const int64_t *mine, int64_t len, int64_t src) {  /* `_reverse` */
    int64_t cut = pb_index(mine, len, src), m = 0, out[PB_MOST];
    for (int64_t k = cut + 1; k < len; k++)
        if (mine[k] >= 0) out[m++] = mine[k];
    out[m++] = src;
    for (int64_t k = 0; k < cut; k++) out[m++] = mine[k];
    pb_copy(f, out, m);
}

/* `_swapped`: the frame's cells to try (from `mine`) and the drone it pulls. */
static void pb_swapped(pb *p, int64_t i, const int64_t *mine, int64_t len, pb_frame *f) {
    int64_t v = len ? mine[0] : -1, src = p->here[i], on[2];
    f->pull = -1;
    if (!p->bits || v < 0 || v == src || pb_index(mine, len, src) < 0 || !pb_open(p, v)) {
        pb_copy(f, mine, len);
        return;
    }
    int64_t j = pb_now(p, v);
    if (j >= 0 && j != i && p->nxt[j] < 0) {
        const int64_t *theirs = p->cand + j * p->W;
        int64_t at_src = pb_index(theirs, p->W, src);
        if (at_src >= 0) {
            int64_t at_v = pb_index(theirs, p->W, v);
            int wants = at_v >= 0 && at_src < at_v;
            if ((wants || p->goal[j] == v) && pb_required(p, i, j, src, v, 0) && pb_beyond(p, v, src, -1, 0, v)) {
                pb_reverse(f, mine, len, src);
                f->pull = j;
                return;
            }
        }
    }
    if (pb_ways(p, v, src, 1, on) >= 2) {
        pb_copy(f, mine, len);
        return;
    }
    for (int64_t s = 0; s < p->S; s++) {
        int64_t k = pb_now(p, src + p->steps[s]);
        if (k < 0 || k == i || p->goal[k] < 0 || p->here[k] == v) continue;
        const int64_t *theirs = p->cand + k * p->W;
        int64_t a = pb_index(theirs, p->W, src), b = pb_index(theirs, p->W, p->here[k]);
        if (a < 0 || b < 0 || a > b) continue;
        if (pb_required(p, k, i, src, v, 1) && pb_beyond(p, v, src, -1, 0, v)) {
            pb_reverse(f, mine, len, src);
            f->pull = p->nxt[k] < 0 ? k : -1;
            return;
        }
    }
    pb_copy(f, mine, len);
}

/* `_out_of_the_way`: the pushed drone's cells (its row `mine`, at `src`; its pusher enters from `leaves`, heading for
   `goal`, -2 when its aim is unknown). */
static void pb_out_of_the_way(const pb *p, const int64_t *mine, int64_t len, int64_t src, int64_t enters,
                              int64_t leaves, int64_t goal, int64_t *out, int64_t *out_len) {
    int64_t cut = pb_index(mine, len, src), later[PB_MOST], nl = 0, m = 0;
    if (cut < 0) {
        memcpy(out, mine, (size_t)len * sizeof(int64_t));
        *out_len = len;
        return;
    }
    int64_t ahead = enters - leaves + enters;
    for (int64_t k = cut + 1; k < len; k++)
        if (mine[k] == ahead) later[nl++] = mine[k];
    if (goal >= 0) {
        int64_t near = pb_manhattan(p, enters, goal);
        if (near < pb_manhattan(p, leaves, goal)) {
            nl = 0;
            for (int64_t k = cut + 1; k < len; k++)
                if (mine[k] >= 0 && (mine[k] == ahead || pb_manhattan(p, mine[k], goal) < near)) later[nl++] = mine[k];
        }
    }
    if (!nl) {
        memcpy(out, mine, (size_t)len * sizeof(int64_t));
        *out_len = len;
        return;
    }
    for (int64_t k = 0; k < len; k++)
        if (mine[k] >= 0 && pb_index(later, nl, mine[k]) < 0) out[m++] = mine[k];
    for (int64_t k = 0; k < nl; k++) out[m++] = later[k];
    *out_len = m;
}

static void pb_pull(pb *p, int64_t i, int64_t j) {  /* `_pull` */
    int64_t src = p->here[i];
    if (p->nxt[j] < 0 && pb_claimed(p, src) < 0 && pb_index(p->cand + j * p->W, p->W, src) >= 0) {
        p->nxt[j] = src;
        p->claimed[src] = (int32_t)(j + 1);
    }
}

/* `pibt`: `nxt` ((n,): the taken cells in, -1 for the drones that choose; their next cells out), `here` (n,), `cand`
   ((n, W), -1 after the last), `order` the drones that choose, highest priority first; `bits` the open cells over `C`
   flat cells (NULL: no swap), `steps` (S,) the flat moves, `goal` (n,) each drone's target for the swap (-1: none),
   `aim` (n,) each drone's target for a pushed drone's retreats (NULL: unknown), `Y`, `Z` the padded shape's last two.
   Writes the drones that gave way into `gave` and returns how many; -1 if it cannot run (W too big, no memory). */
int64_t pb_pibt(int64_t n, int64_t W, const int64_t *here, const int64_t *cand, const int64_t *order, int64_t n_order,
                int64_t *nxt, const uint8_t *bits, int64_t C, const int64_t *steps, int64_t S, const int64_t *goal,
                const int64_t *aim, int64_t Y, int64_t Z, int64_t *gave) {
    if (W > PB_MOST || n <= 0) return n <= 0 ? 0 : -1;
    for (int64_t i = 0; i < n; i++) {  /* cells off the flat range: not ours to index (Python's then) */
        if (here[i] < 0 || here[i] >= C || nxt[i] >= C || goal[i] >= C || (aim && aim[i] >= C)) return -1;
        for (int64_t k = 0; k < W; k++)
            if (cand[i * W + k] >= C) return -1;
    }
    for (int64_t r = 0; r < n_order; r++)
        if (order[r] < 0 || order[r] >= n) return -1;
    pb p = {n, W, C, S, Y, Z, here, cand, goal, aim, steps, bits, nxt, NULL, NULL, NULL, NULL, 0, 0};
    p.now = calloc((size_t)C, sizeof(int32_t));
    p.claimed = calloc((size_t)C, sizeof(int32_t));
    p.wr = calloc((size_t)C, sizeof(int32_t));
    p.wb = calloc((size_t)C, sizeof(int32_t));
    uint8_t *tree = calloc((size_t)n, 1);
    int64_t *members = malloc((size_t)n * sizeof(int64_t));
    pb_frame *stack = malloc((size_t)(n + 1) * sizeof(pb_frame));
    int64_t ng = -1;
    if (!p.now || !p.claimed || !p.wr || !p.wb || !tree || !members || !stack) goto done;
    for (int64_t i = 0; i < n; i++) p.now[here[i]] = (int32_t)(i + 1);
    for (int64_t i = 0; i < n; i++)
        if (nxt[i] >= 0) p.claimed[nxt[i]] = (int32_t)(i + 1);
    ng = 0;
    for (int64_t r = 0; r < n_order; r++) {
        int64_t root = order[r];
        if (nxt[root] >= 0) continue;  /* moved already, pushed by a drone of higher priority */
        int64_t top = 0, nm = 0;
        stack[0].i = root;
        stack[0].k = 0;
        pb_swapped(&p, root, cand + root * W, W, &stack[0]);
        tree[root] = 1;
        members[nm++] = root;
        int contested = 0, led = stack[0].pull >= 0, ok = -1;  /* ok: -1 None, 0 False, 1 True */
        while (top >= 0) {
            pb_frame *fr = &stack[top];
            int64_t i = fr->i, k = fr->k, pull = fr->pull;
            if (ok == 1) {
                if (pull >= 0 && k == 1) pb_pull(&p, i, pull);
                top--;
                continue;
            }
            ok = -1;
            int64_t src = here[i];
            int pushed = 0;
            while (k < fr->len) {
                int64_t v = fr->mine[k++];
                if (v < 0) break;
                int64_t c = pb_claimed(&p, v);
                if (c >= 0) {
                    contested = contested || !tree[c];
                    continue;
                }
                int64_t j = pb_now(&p, v);
                if (j >= 0 && j != i && nxt[j] == src) {  /* a swap */
                    contested = contested || !tree[j];
                    continue;
                }
                nxt[i] = v;
                p.claimed[v] = (int32_t)(i + 1);
                if (j >= 0 && j != i && nxt[j] < 0) {  /* priority inheritance: j must make room */
                    fr->k = k;
                    int64_t theirs[PB_MOST], nt = 0;
                    pb_out_of_the_way(&p, cand + j * W, W, here[j], v, src, aim ? aim[i] : -2, theirs, &nt);
                    pb_frame *child = &stack[++top];
                    child->i = j;
                    child->k = 0;
                    pb_swapped(&p, j, theirs, nt, child);
                    if (!tree[j]) {
                        tree[j] = 1;
                        members[nm++] = j;
                    }
                    pushed = 1;
                    break;
                }
                if (pull >= 0 && k == 1) pb_pull(&p, i, pull);
                ok = 1;
                break;
            }
            if (pushed) continue;
            if (ok != 1) {  /* every candidate failed: it stays */
                nxt[i] = src;
                p.claimed[src] = (int32_t)(i + 1);
                ok = 0;
            }
            top--;
        }
        if (!contested && !led && nxt[root] != cand[root * W]) gave[ng++] = root;
        for (int64_t m = 0; m < nm; m++) tree[members[m]] = 0;
    }
done:
    free(p.now);
    free(p.claimed);
    free(p.wr);
    free(p.wb);
    free(tree);
    free(members);
    free(stack);
    return ng;
}

/* A search node's candidates (coordinator/lacam.py's `Search._candidates` with coordinator/arbiter.py's `candidates`,
   `hindrance` and `tie_breaks`), compiled for the same search: each drone's cells (its open neighbours and its own)
   ranked by its distance table, then reordered as the arbiter orders them, then its scattered path's next cell first.
   The same rows as Python's (tests/test_lacam.py): every key as Python's numpy computes it, each row sorted stably.
   `c` (n,) the drones' numbered cells, `near` (F, K) the numbered neighbours (-1: none), `dist` (n, F) int16 tables,
   `cells` (F,) numbered -> flat, `here` (n,) flat, `targets` (n,) flat or -1 (NULL: none), `salted`/`seed` the
   tie-breaks' (`tie_breaks`' seed, Python's salt already mixed), `Y`, `Z` the padded shape's last two, `C` the flat
   cells, `guide` (n,) each drone's scattered next cell or -1 (NULL: none); `out` (n, K + 1). 0; -1 without memory or with a drone's cell off its range (`near` and `cells` the caller checks once). */

#define TIE_BITS 16
#define M2 0xBF58476D1CE4E5B9ULL
#define M3 0x94D049BB133111EBULL

static void pb_sort(int64_t *key, int64_t *val, int64_t m) {  /* stable: insertion */
    for (int64_t a = 1; a < m; a++) {
        int64_t k = key[a], v = val[a], b = a - 1;
        while (b >= 0 && key[b] > k) {
            key[b + 1] = key[b];
            val[b + 1] = val[b];
            b--;
        }
        key[b + 1] = k;
        val[b + 1] = v;
    }
}

int64_t pb_candidates(int64_t n, int64_t K, const int64_t *c, const int64_t *near, const int16_t *dist, int64_t F,
                      const int64_t *cells, const int64_t *here, const int64_t *targets, int64_t salted,
                      uint64_t seed, int64_t Y, int64_t Z, int64_t C, const int64_t *guide, int64_t *out) {
    const int64_t W = K + 1;
    if (W > PB_MOST) return -1;
    for (int64_t i = 0; i < n; i++)  /* cells off their ranges: not ours to index (Python's then); the graph's own
                                         (`near`, `cells`) its caller checks once, not at every node */
        if (here[i] < 0 || here[i] >= C || c[i] < 0 || c[i] >= F || (targets && targets[i] >= C)) return -1;
    int32_t *at = calloc((size_t)C, sizeof(int32_t));  /* cell -> drone + 1 */
    uint8_t *aimed = calloc((size_t)C, 1);              /* cell -> some drone's target */
    int64_t *hind = calloc((size_t)(n * W), sizeof(int64_t));
    int64_t *stay_at = malloc((size_t)n * sizeof(int64_t));
    if (!at || !aimed || !hind || !stay_at) {
        free(at); free(aimed); free(hind); free(stay_at);
        return -1;
    }
    pb geo = {0};
    geo.Y = Y;
    geo.Z = Z;
    for (int64_t i = 0; i < n; i++) at[here[i]] = (int32_t)(i + 1);
    if (targets)
        for (int64_t i = 0; i < n; i++)
            if (targets[i] >= 0) aimed[targets[i]] = 1;
    /* each drone's own order: nearest to its goal first, staying before a neighbour as near (`rank`) */
    for (int64_t i = 0; i < n; i++) {
        int64_t key[PB_MOST], val[PB_MOST];
        const int64_t *nb = near + c[i] * K;
        for (int64_t k = 0; k < W; k++) {
            int64_t v = k < K ? nb[k] : c[i];
            key[k] = v >= 0 ? (int64_t)dist[i * F + v] * 8 + (k < K ? k + 1 : 0) : ((int64_t)1 << 40);
            val[k] = v >= 0 ? cells[v] : -1;
        }
        pb_sort(key, val, W);
        int64_t *row = out + i * W;
        stay_at[i] = W;  /* (Python's MOST: no cell is its own) */
        for (int64_t k = 0; k < W; k++) {
            row[k] = val[k];
            if (stay_at[i] == W && val[k] == here[i]) stay_at[i] = k;
        }
    }
    /* `hindrance`: a drone j that wants (ranks before staying) a cell another drone i stands in, j with a target:
       i's candidates closer (Manhattan) to j's target than i's cell, other than j's cell, count once each */
    if (targets) {
        for (int64_t j = 0; j < n; j++) {
            if (targets[j] < 0) continue;
            const int64_t *row = out + j * W;
            for (int64_t k = 0; k < stay_at[j] && k < W; k++) {
                int64_t v = row[k];
                if (v < 0 || v == here[j] || !at[v]) continue;
                int64_t i = at[v] - 1, goal = targets[j], mine = pb_manhattan(&geo, here[i], goal);
                const int64_t *theirs = out + i * W;
                for (int64_t kk = 0; kk < W; kk++) {
                    int64_t u = theirs[kk];
                    if (u >= 0 && u != here[j] && pb_manhattan(&geo, u, goal) < mine) hind[i * W + kk]++;
                }
            }
        }
    }
    /* `candidates`' keys, each row sorted stably, then the scattered path's next cell first */
    for (int64_t i = 0; i < n; i++) {
        int64_t key[PB_MOST], val[PB_MOST];
        int64_t *row = out + i * W, w = stay_at[i];
        int ranks_stay = w < W;
        for (int64_t k = 0; k < W; k++) {
            int64_t v = row[k], major = 0, minor = k;
            if (ranks_stay) {
                int occupied = v >= 0 && at[v] && v != here[i];
                int theirs = targets && v >= 0 && aimed[v] && v != targets[i];
                int64_t h = k > w ? (hind[i * W + k] < 7 ? hind[i * W + k] : 7) : 0;
                major = (k > w) * 512 + (k == w) * 256 + occupied * 128 + h * 8 + theirs * 4;
                if (salted && k > w) {
                    uint64_t x = seed + (uint64_t)here[i] * M2 + (uint64_t)v * M3;
                    x ^= x >> 30;
                    x *= M2;
                    x ^= x >> 27;
                    x *= M3;
                    x ^= x >> 31;
                    minor = (int64_t)(x >> (64 - TIE_BITS));
                }
            }
            key[k] = v < 0 ? ((int64_t)1024 << TIE_BITS) : (major << TIE_BITS) + minor;
            val[k] = v;
        }
        pb_sort(key, val, W);
        int64_t first = guide ? guide[i] : -1, hit = -1;
        for (int64_t k = 0; k < W && first >= 0; k++)
            if (val[k] == first) hit = k;
        if (hit > 0) {
            for (int64_t k = hit; k > 0; k--) val[k] = val[k - 1];
            val[0] = first;
        }
        memcpy(row, val, (size_t)W * sizeof(int64_t));
    }
    free(at);
    free(aimed);
    free(hind);
    free(stay_at);
    return 0;
}

/* A search node's PIBT call made ready (coordinator/lacam.py's `Search._choosers` with `_choosing`): `taken` (n,) the
   cells the node's constraints send drones to (-1: none), `order` (n,) PIBT's order of every drone. `out` gets the
   order's drones that no constraint sends (in order); the count of those that must choose is returned: not the drones
   at its end whose first candidate (`cand`, (n, W)) is their own cell (`here`, flat) and into whose cell no constraint
   sends a drone. -2 where two constraints send drones to one cell (no call); -1 with a cell off its range (`C` the
   flat cells: Python's then). */
int64_t pb_choosers(int64_t n, int64_t W, const int64_t *here, const int64_t *cand, const int64_t *order,
                    const int64_t *taken, int64_t C, int64_t *out) {
    for (int64_t i = 0; i < n; i++)
        if (here[i] < 0 || here[i] >= C || taken[i] >= C || order[i] < 0 || order[i] >= n) return -1;
    uint8_t *fixed = calloc((size_t)C, 1);
    if (!fixed) return -1;
    int64_t m = 0, k;
    for (int64_t i = 0; i < n; i++) {
        if (taken[i] < 0) continue;
        if (fixed[taken[i]]) {
            free(fixed);
            return -2;
        }
        fixed[taken[i]] = 1;
    }
    for (int64_t r = 0; r < n; r++)
        if (taken[order[r]] < 0) out[m++] = order[r];
    for (k = m; k > 0; k--) {
        int64_t i = out[k - 1];
        if (cand[i * W] != here[i] || fixed[here[i]]) break;
    }
    free(fixed);
    return k;
}

/* A PIBT call's next cells made whole and checked (coordinator/lacam.py's `Search._successor`): a drone that neither
   chose nor was taken (-1 in `nxt`) stays (`nxt` written so); 1 if no two drones share a cell and no two swap theirs,
   0 if some do, -1 with a cell off its range (`C` the flat cells: Python's check then). */
int64_t pb_valid(int64_t n, const int64_t *here, int64_t *nxt, int64_t C) {
    for (int64_t i = 0; i < n; i++)
        if (here[i] < 0 || here[i] >= C || nxt[i] >= C) return -1;
    int32_t *now = calloc((size_t)C, sizeof(int32_t)), *next = calloc((size_t)C, sizeof(int32_t));
    int64_t ok = 1;
    if (!now || !next) ok = -1;
    for (int64_t i = 0; ok == 1 && i < n; i++) {
        if (nxt[i] < 0) nxt[i] = here[i];
        now[here[i]] = (int32_t)(i + 1);
    }
    for (int64_t i = 0; ok == 1 && i < n; i++) {
        if (next[nxt[i]]) ok = 0;  /* two drones in one cell */
        next[nxt[i]] = (int32_t)(i + 1);
        int64_t j = now[nxt[i]] - 1;
        if (j >= 0 && j != i && nxt[j] == here[i]) ok = 0;  /* a swap */
    }
    free(now);
    free(next);
    return ok;
}
