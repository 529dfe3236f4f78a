/* Segment integration of a slave piece against a master triangle, and its tangent.
 *
 * The same arithmetic as the numpy reference (geometry.overlap_polygons, geometry.fan_rule,
 * geometry.barycentric_2d, segment_tangent.segment_geometry and segment_tangent.segment_loads),
 * one (slave piece, master triangle) pair at a time: the numpy code works a perturbed copy of
 * every pair as one more row of its arrays, and its temporaries cost more than the arithmetic.
 * Compiled on first use (kernel.py); the numpy code stays the reference the tests compare with.
 */
#include <math.h>
#include <string.h>

#define MAXV 24            /* polygon vertices: 3 -> 6 -> 12 -> 24 at most (Sutherland-Hodgman) */
#define MAXQ 16            /* points of the rule on one fan triangle */
#define MAXP (MAXV * MAXQ)      /* the centroid fan: one triangle per vertex */
#define MAXK 12            /* nodes of a pair: 6 slave + 6 master (P2) */

static const double NODE_MU[6][3] = {
    {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0.5, 0.5, 0}, {0, 0.5, 0.5}, {0.5, 0, 0.5}};

static void cross(const double *a, const double *b, double *c)
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

static void p2_shape(const double *m, double *N)
{
    N[0] = m[0] * (2 * m[0] - 1);
    N[1] = m[1] * (2 * m[1] - 1);
    N[2] = m[2] * (2 * m[2] - 1);
    N[3] = 4 * m[0] * m[1];
    N[4] = 4 * m[1] * m[2];
    N[5] = 4 * m[2] * m[0];
}

static void barycentric_2d(const double *p, const double *t, double *lam)
{
    double v0x = t[2] - t[0], v0y = t[3] - t[1], v1x = t[4] - t[0], v1y = t[5] - t[1];
    double dx = p[0] - t[0], dy = p[1] - t[1];
    double det = v0x * v1y - v0y * v1x;
    double l1 = (dx * v1y - dy * v1x) / det;
    double l2 = (v0x * dy - v0y * dx) / det;
    lam[0] = 1.0 - l1 - l2;
    lam[1] = l1;
    lam[2] = l2;
}

/* Clip a convex polygon to the left of a -> b (the vertex, then the crossing). */
static int clip(const double *in, int cnt, const double *a, const double *b, double *out)
{
    double ex = b[0] - a[0], ey = b[1] - a[1];
    int n = 0;
    for (int j = 0; j < cnt; ++j) {
        const double *cur = in + 2 * j, *nx = in + 2 * ((j + 1) % cnt);
        double dc = ex * (cur[1] - a[1]) - ey * (cur[0] - a[0]);
        double dn = ex * (nx[1] - a[1]) - ey * (nx[0] - a[0]);
        int inc = dc >= 0, inn = dn >= 0;
        if (inc && n < MAXV) {
            out[2 * n] = cur[0];
            out[2 * n + 1] = cur[1];
            ++n;
        }
        if (inc != inn && n < MAXV) {
            double den = dc != dn ? dc - dn : 1.0;
            double t = dc / den;
            t = t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
            out[2 * n] = cur[0] + t * (nx[0] - cur[0]);
            out[2 * n + 1] = cur[1] + t * (nx[1] - cur[1]);
            ++n;
        }
    }
    return n;
}

/* The distance of a vertex of either 2D triangle (3x2 each) from the line of an edge of the
 * other: the cut's kinks (its polygon changes shape when one crosses a line). */
static double cut_kink(const double *s2, const double *m2)
{
    double d = HUGE_VAL;
    const double *tri[2] = {s2, m2};
    for (int o = 0; o < 2; ++o) {
        const double *E = tri[o], *V = tri[1 - o];
        for (int e = 0; e < 3; ++e) {
            const double *a = E + 2 * e, *b = E + 2 * ((e + 1) % 3);
            double ex = b[0] - a[0], ey = b[1] - a[1], l = sqrt(ex * ex + ey * ey);
            for (int v = 0; v < 3; ++v) {
                double dv = fabs(ex * (V[2 * v + 1] - a[1]) - ey * (V[2 * v] - a[0])) / l;
                d = dv < d ? dv : d;
            }
        }
    }
    return d;
}

/* geometry.facing_weight: the factor of a pair's weights at c = -ns . nm (0 up to
 * FACING_MIN, 1 from FACING_FULL, a C1 cubic between; the same constants as geometry.py). */
#define FACING_MIN 0.05
#define FACING_FULL 0.2
static double facing_weight(double c)
{
    double t = (c - FACING_MIN) / (FACING_FULL - FACING_MIN);
    t = t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
    return t * t * (3.0 - 2.0 * t);
}

/* The points of a slave piece P (3x3, counter-clockwise about its unit normal ns) on its
 * overlap with a master triangle T (3x3): barycentric coordinates on the piece (lam) and on
 * T in its own vertex order (beta), weights as fractions of the piece's area (W); with kink
 * not NULL, its cut_kink. */
static int cut_pair(const double *P, const double *ns, const double *T, int nq,
                    const double *mu, const double *w, double *lam, double *beta, double *W,
                    double *kink)
{
    double e1[3], e2[3], s2[6], m2[6], mc[6], bufa[2 * MAXV], bufb[2 * MAXV];
    for (int i = 0; i < 3; ++i)
        e1[i] = P[3 + i] - P[i];
    double l = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]);
    for (int i = 0; i < 3; ++i)
        e1[i] /= l;
    cross(ns, e1, e2);
    for (int v = 0; v < 3; ++v) {
        double d[3], dt[3];
        for (int i = 0; i < 3; ++i) {
            d[i] = P[3 * v + i] - P[i];
            dt[i] = T[3 * v + i] - P[i];
        }
        s2[2 * v] = d[0] * e1[0] + d[1] * e1[1] + d[2] * e1[2];
        s2[2 * v + 1] = d[0] * e2[0] + d[1] * e2[1] + d[2] * e2[2];
        m2[2 * v] = dt[0] * e1[0] + dt[1] * e1[1] + dt[2] * e1[2];
        m2[2 * v + 1] = dt[0] * e2[0] + dt[1] * e2[1] + dt[2] * e2[2];
    }
    if (kink)
        *kink = cut_kink(s2, m2);
    double det = (m2[2] - m2[0]) * (m2[5] - m2[1]) - (m2[3] - m2[1]) * (m2[4] - m2[0]);
    memcpy(mc, m2, sizeof mc);
    if (det < 0) { /* counter-clockwise master */
        mc[2] = m2[4];
        mc[3] = m2[5];
        mc[4] = m2[2];
        mc[5] = m2[3];
    }
    memcpy(bufa, s2, sizeof s2);
    int cnt = 3;
    cnt = clip(bufa, cnt, mc, mc + 2, bufb);
    cnt = clip(bufb, cnt, mc + 2, mc + 4, bufa);
    cnt = clip(bufa, cnt, mc + 4, mc, bufb);
    double *poly = bufb;
    double s_area = 0.5 * fabs((s2[2] - s2[0]) * (s2[5] - s2[1]) - (s2[3] - s2[1]) * (s2[4] - s2[0]));
    /* the fan about the polygon's area centroid (geometry.fan_rule: it moves continuously
     * with the polygon, a fan about a vertex does not), coordinates about the first vertex */
    double rel[2 * MAXV], area2 = 0.0, cx = 0.0, cy = 0.0;
    for (int j = 0; j < cnt; ++j) {
        rel[2 * j] = poly[2 * j] - poly[0];
        rel[2 * j + 1] = poly[2 * j + 1] - poly[1];
    }
    for (int j = 0; j < cnt; ++j) {
        const double *B = rel + 2 * j, *C = rel + 2 * ((j + 1) % cnt);
        double c = B[0] * C[1] - B[1] * C[0];
        area2 += c;
        cx += c * (B[0] + C[0]);
        cy += c * (B[1] + C[1]);
    }
    int q = 0;
    if (cnt < 3 || !(fabs(area2) > 2e-12 * s_area))
        return 0;
    double A[2] = {cx / (3.0 * area2), cy / (3.0 * area2)};
    for (int f = 0; f < cnt; ++f) {
        const double *B = rel + 2 * f, *C = rel + 2 * ((f + 1) % cnt);
        double tri2 = 0.5 * ((B[0] - A[0]) * (C[1] - A[1]) - (B[1] - A[1]) * (C[0] - A[0]));
        if (!(fabs(tri2) > 1e-12 * s_area))
            continue;
        for (int k = 0; k < nq; ++k) {
            double p[2];
            for (int d = 0; d < 2; ++d)
                p[d] = mu[3 * k] * A[d] + mu[3 * k + 1] * B[d] + mu[3 * k + 2] * C[d] + poly[d];
            barycentric_2d(p, s2, lam + 3 * q);
            barycentric_2d(p, m2, beta + 3 * q);
            W[q] = fabs(tri2) * w[k] / s_area;
            ++q;
        }
    }
    return q;
}

/* Candidate pairs (M): pieces P (M,3,3) with unit normals ns (M,3), master triangles T (M,3,3).
 * Writes at most cap points (pair rr, lam, beta, W) and returns how many there are. */
long sf_cut(long M, const double *P, const double *ns, const double *T, int nq,
            const double *mu, const double *w, long cap, long *rr, double *lam, double *beta,
            double *W)
{
    double l[3 * MAXP], b[3 * MAXP], ww[MAXP];
    long total = 0;
    if (nq > MAXQ)
        return -1;
    for (long m = 0; m < M; ++m) {
        int q = cut_pair(P + 9 * m, ns + 3 * m, T + 9 * m, nq, mu, w, l, b, ww, NULL);
        for (int k = 0; k < q; ++k, ++total) {
            if (total >= cap)
                continue;
            rr[total] = m;
            memcpy(lam + 3 * total, l + 3 * k, 3 * sizeof(double));
            memcpy(beta + 3 * total, b + 3 * k, 3 * sizeof(double));
            W[total] = ww[k];
        }
    }
    return total;
}

typedef struct {
    int ns, nm;              /* slave and master nodes of a pair */
    int nq;                  /* points of the rule */
    const double *mu, *w;    /* the rule */
    int augmented;           /* pressure law: 0 penalty, 1 augmented Lagrangian */
    double penalty, smoothing, depth;
} Law;

typedef struct {
    int q;
    double N1[3 * MAXP], N[6 * MAXP], Nm[6 * MAXP], W[MAXP], n[3];
} Geometry;

/* segment_geometry of one pair at its nodes' positions Y (k,3); with kink not NULL, the
 * cut's cut_kink. */
static void pair_geometry(const Law *L, const double *Y, const long *cols, const long *mv,
                          const double *tmu, double ref_area, Geometry *G, double *kink)
{
    double P[9], T[9], a[3], b[3], nsv[3], lam[3 * MAXP], beta[3 * MAXP];
    for (int v = 0; v < 3; ++v)
        for (int i = 0; i < 3; ++i) {
            P[3 * v + i] = Y[3 * cols[v] + i];
            T[3 * v + i] = Y[3 * (L->ns + mv[v]) + i];
        }
    for (int i = 0; i < 3; ++i) {
        a[i] = P[3 + i] - P[i];
        b[i] = P[6 + i] - P[i];
    }
    cross(a, b, nsv);
    double l = sqrt(nsv[0] * nsv[0] + nsv[1] * nsv[1] + nsv[2] * nsv[2]);
    for (int i = 0; i < 3; ++i)
        nsv[i] /= l;
    G->q = cut_pair(P, nsv, T, L->nq, L->mu, L->w, lam, beta, G->W, kink);
    for (int k = 0; k < G->q; ++k) {
        double *N1 = G->N1 + 3 * k;
        G->W[k] *= ref_area;
        for (int j = 0; j < 3; ++j)
            N1[j] = lam[3 * k] * NODE_MU[cols[0]][j] + lam[3 * k + 1] * NODE_MU[cols[1]][j] +
                    lam[3 * k + 2] * NODE_MU[cols[2]][j];
        if (L->ns == 6)
            p2_shape(N1, G->N + 6 * k);
        else
            memcpy(G->N + 6 * k, N1, 3 * sizeof(double));
        if (tmu) {
            double m[3];
            for (int j = 0; j < 3; ++j)
                m[j] = beta[3 * k] * tmu[j] + beta[3 * k + 1] * tmu[3 + j] + beta[3 * k + 2] * tmu[6 + j];
            p2_shape(m, G->Nm + 6 * k);
        } else {
            memcpy(G->Nm + 6 * k, beta + 3 * k, 3 * sizeof(double));
        }
    }
    for (int i = 0; i < 3; ++i) {
        a[i] = T[3 + i] - T[i];
        b[i] = T[6 + i] - T[i];
    }
    cross(a, b, G->n);
    l = sqrt(G->n[0] * G->n[0] + G->n[1] * G->n[1] + G->n[2] * G->n[2]);
    l = l > 1e-300 ? l : 1e-300;
    for (int i = 0; i < 3; ++i)
        G->n[i] /= l;
    double wf = facing_weight(-(nsv[0] * G->n[0] + nsv[1] * G->n[1] + nsv[2] * G->n[2]));
    for (int k = 0; k < G->q; ++k)
        G->W[k] *= wf;
}

static double pressure(const Law *L, double g, double lam)
{
    double p;
    if (L->augmented) {
        p = lam - L->penalty * g;
        p = p > 0 ? p : 0.0;
    } else if (L->smoothing == 0.0) {
        p = -g > 0 ? L->penalty * -g : 0.0;
    } else {
        double s = L->smoothing, d = -g, mid = d + s;
        mid = mid < 0 ? 0 : (mid > 2 * s ? 2 * s : mid);
        p = d > s ? L->penalty * d : L->penalty * mid * mid / (4 * s);
    }
    return g >= -L->depth ? p : 0.0;
}

/* How far (m of gap) the argument of the pressure law is from a kink or jump of it: g = 0
 * (plain penalty), lam - penalty g = 0 (augmented), g = -depth (the search depth). The
 * smoothed law is C1 and has none. */
static double kink_distance(const Law *L, double g, double lam)
{
    double d = fabs(g + L->depth);
    double k = L->augmented ? fabs(lam - L->penalty * g) / L->penalty
                            : (L->smoothing == 0.0 ? fabs(g) : d);
    return k < d ? k : d;
}

/* segment_loads of one pair: the residual contributions R (k,3) at Y with the points G; with
 * kink not NULL, the smallest kink_distance of its points. */
static void pair_loads(const Law *L, const Geometry *G, const double *Y, const double *lam_f,
                       double *R, double *kink)
{
    int k = L->ns + L->nm;
    memset(R, 0, 3 * k * sizeof(double));
    for (int q = 0; q < G->q; ++q) {
        const double *N = G->N + 6 * q, *Nm = G->Nm + 6 * q, *N1 = G->N1 + 3 * q;
        double xq[3] = {0, 0, 0}, xm[3] = {0, 0, 0};
        for (int a = 0; a < L->ns; ++a)
            for (int i = 0; i < 3; ++i)
                xq[i] += N[a] * Y[3 * a + i];
        for (int b = 0; b < L->nm; ++b)
            for (int i = 0; i < 3; ++i)
                xm[i] += Nm[b] * Y[3 * (L->ns + b) + i];
        double g = (xq[0] - xm[0]) * G->n[0] + (xq[1] - xm[1]) * G->n[1] + (xq[2] - xm[2]) * G->n[2];
        double lam = N1[0] * lam_f[0] + N1[1] * lam_f[1] + N1[2] * lam_f[2];
        if (kink) {
            double d = kink_distance(L, g, lam);
            *kink = d < *kink ? d : *kink;
        }
        double pw = pressure(L, g, lam) * G->W[q];
        if (pw == 0.0)
            continue;
        for (int a = 0; a < L->ns; ++a)
            for (int i = 0; i < 3; ++i)
                R[3 * a + i] -= N[a] * pw * G->n[i];
        for (int b = 0; b < L->nm; ++b)
            for (int i = 0; i < 3; ++i)
                R[3 * (L->ns + b) + i] += Nm[b] * pw * G->n[i];
    }
}

/* The tangent blocks of M pairs, blk (M, k, 3, k, 3) = d(R of the pair)/d(Y of the pair), by
 * forward differences of step h in every node coordinate, or central ones for a pair within
 * near of a kink: a point's of the pressure law (kink_distance) or the cut's (cut_kink). A
 * one-sided difference takes a kink as all or nothing. The nodes that move the segments'
 * points (the piece's vertices cols, the master triangle's mv) are cut anew at every copy;
 * the others keep the pair's points. Y (M,k,3), cols and mv (M,3), tmu (M,3,3) or NULL,
 * ref_area (M,), lam_f (M,3): the slave facet's multipliers at its vertices. central (M,): set
 * to 1 where central. */
void sf_tangent(long M, int ns, int nm, const double *Y, const long *cols, const long *mv,
                const double *tmu, const double *ref_area, const double *lam_f, int nq,
                const double *mu, const double *w, int augmented, double penalty,
                double smoothing, double depth, double h, double near, double *blk,
                char *central)
{
    Law L = {ns, nm, nq, mu, w, augmented, penalty, smoothing, depth};
    int k = ns + nm;
    Geometry base, moved;
    double Yp[3 * MAXK], Rp[3 * MAXK], Rm[3 * MAXK], R0[3 * MAXK];
    for (long m = 0; m < M; ++m) {
        const double *Ym = Y + 3 * k * m;
        const long *c = cols + 3 * m, *v = mv + 3 * m;
        const double *t = tmu ? tmu + 9 * m : NULL;
        double *B = blk + 9 * k * k * m;
        int cut[MAXK] = {0};
        double kink = HUGE_VAL;
        for (int j = 0; j < 3; ++j) {
            cut[c[j]] = 1;
            cut[ns + v[j]] = 1;
        }
        pair_geometry(&L, Ym, c, v, t, ref_area[m], &base, &kink);
        pair_loads(&L, &base, Ym, lam_f + 3 * m, R0, &kink);
        central[m] = kink < near;
        memcpy(Yp, Ym, 3 * k * sizeof(double));
        for (int b = 0; b < k; ++b)
            for (int j = 0; j < 3; ++j) {
                double y0 = Ym[3 * b + j];
                const Geometry *G = &base;
                Yp[3 * b + j] = y0 + h;
                if (cut[b]) {
                    pair_geometry(&L, Yp, c, v, t, ref_area[m], &moved, NULL);
                    G = &moved;
                }
                pair_loads(&L, G, Yp, lam_f + 3 * m, Rp, NULL);
                if (central[m]) {
                    Yp[3 * b + j] = y0 - h;
                    if (cut[b])
                        pair_geometry(&L, Yp, c, v, t, ref_area[m], &moved, NULL);
                    pair_loads(&L, G, Yp, lam_f + 3 * m, Rm, NULL);
                }
                Yp[3 * b + j] = y0;
                for (int a = 0; a < 3 * k; ++a)
                    B[a * 3 * k + 3 * b + j] = central[m] ? (Rp[a] - Rm[a]) / (2 * h)
                                                          : (Rp[a] - R0[a]) / h;
            }
    }
}

/* Slave positions and master side of n segment points (points.segment_gaps and the slave
 * position of evaluation.evaluate_pair): the point xq = sum_a N_a x(slave node a) on its
 * slave facet; on its master triangle t (vertices index[t], unit normal from them), the master
 * nodes and weights (P2 master, parent != NULL: the parent facet's 6 nodes and P2 functions at
 * the point's place in the parent, from tri_mu; else the triangle's 3 vertices and bary3) and
 * the gap g = (xq - xm) . n. kk = 6 with a parent, else 3. */
void sf_gaps(long n, int nn, const long *facet, const long *snodes, const double *N,
             const double *x, const long *t, const double *bary3, const long *index,
             const long *parent, const double *tri_mu, const double *mx, long *m_idx,
             double *bary, double *xq, double *nrm, double *g)
{
    int kk = parent ? 6 : 3;
    for (long q = 0; q < n; ++q) {
        double p[3] = {0, 0, 0};
        const long *sn = snodes + facet[q] * nn;
        for (int a = 0; a < nn; ++a)
            for (int i = 0; i < 3; ++i)
                p[i] += N[q * nn + a] * x[3 * sn[a] + i];
        const long *v = index + 3 * t[q];
        const double *v0 = mx + 3 * v[0], *v1 = mx + 3 * v[1], *v2 = mx + 3 * v[2];
        double e1[3], e2[3], c[3];
        for (int i = 0; i < 3; ++i) {
            e1[i] = v1[i] - v0[i];
            e2[i] = v2[i] - v0[i];
        }
        cross(e1, e2, c);
        double len = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        if (len < 1e-300)
            len = 1e-300;
        for (int i = 0; i < 3; ++i)
            c[i] /= len;
        long *mi = m_idx + q * kk;
        double *b = bary + q * kk;
        const double *b3 = bary3 + 3 * q;
        if (parent) {
            const double *tm = tri_mu + 9 * t[q];
            double mu[3];
            for (int j = 0; j < 3; ++j)
                mu[j] = b3[0] * tm[j] + b3[1] * tm[3 + j] + b3[2] * tm[6 + j];
            p2_shape(mu, b);
            for (int a = 0; a < 6; ++a)
                mi[a] = parent[6 * t[q] + a];
        } else {
            for (int a = 0; a < 3; ++a) {
                b[a] = b3[a];
                mi[a] = v[a];
            }
        }
        double xm[3] = {0, 0, 0};
        for (int a = 0; a < kk; ++a)
            for (int i = 0; i < 3; ++i)
                xm[i] += b[a] * mx[3 * mi[a] + i];
        for (int i = 0; i < 3; ++i) {
            xq[3 * q + i] = p[i];
            nrm[3 * q + i] = c[i];
        }
        g[q] = (p[0] - xm[0]) * c[0] + (p[1] - xm[1]) * c[1] + (p[2] - xm[2]) * c[2];
    }
}
