// Tile-based Gaussian compositing on the CPU (forward and backward), gsplat's rules:
// alpha = min(0.999, o * exp(-sigma)); skip alpha < 1/255 or sigma < 0; stop before the
// Gaussian that would take the transmittance T to <= 1e-4; pixel centres at +0.5.
// Gaussians arrive sorted front to back, so binning them in order keeps every tile's list
// depth-sorted. The backward pass walks each pixel's list back to front, recovering T by
// division as gsplat does, and accumulates gradients in per-thread buffers.
#include "kernels.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <type_traits>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace {

constexpr int64_t TILE = 16;
constexpr int32_t LANES = TILE;  // a row of a tile: the pixels the vectorised loops take at once
constexpr int64_t AHEAD = 8;      // entries ahead whose scattered per-Gaussian data is prefetched
constexpr double ALPHA_MIN = 1.0 / 255.0;
constexpr double ALPHA_MAX = 0.999;
constexpr double T_MIN = 1e-4;

int thread_id() {
#ifdef _OPENMP
    return omp_get_thread_num();
#else
    return 0;
#endif
}

}  // namespace

namespace eve3d {

int max_threads() {
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

void bin_tiles(const int64_t* b, const int64_t* vis, int64_t n, int64_t width, int64_t height,
               std::vector<int64_t>& counts, std::vector<int64_t>& ids) {
    const int64_t tiles_x = (width + TILE - 1) / TILE, tiles_y = (height + TILE - 1) / TILE;
    counts.assign(tiles_x * tiles_y + 1, 0);
    for (int64_t g = 0; g < n; ++g) {
        const int64_t* bg = b + 4 * g;
        if (bg[2] < bg[0] || bg[3] < bg[1]) continue;
        for (int64_t ty = bg[1] / TILE; ty <= bg[3] / TILE; ++ty)
            for (int64_t tx = bg[0] / TILE; tx <= bg[2] / TILE; ++tx) counts[ty * tiles_x + tx + 1]++;
    }
    for (size_t i = 1; i < counts.size(); ++i) counts[i] += counts[i - 1];
    ids.resize(counts.back());
    std::vector<int64_t> fill(counts.begin(), counts.end() - 1);
    for (int64_t g = 0; g < n; ++g) {
        const int64_t* bg = b + 4 * g;
        if (bg[2] < bg[0] || bg[3] < bg[1]) continue;
        for (int64_t ty = bg[1] / TILE; ty <= bg[3] / TILE; ++ty)
            for (int64_t tx = bg[0] / TILE; tx <= bg[2] / TILE; ++tx) ids[fill[ty * tiles_x + tx]++] = vis[g];
    }
}

}  // namespace eve3d

namespace {

// exp(x) in a form the compiler vectorises across a row of pixels (glibc's vector exp needs
// -ffast-math, which would also drop the NaN tests below): x = n ln2 + r with |r| <= ln2 / 2,
// exp(r) by its Taylor polynomial (degree 7 in float, 13 in double: truncation below half an
// ulp), times 2^n built in the exponent bits. Within a few ulp of std::exp; arguments
// outside [-80, 80] (and NaN) are clamped, as only masked-out pixels reach them.
template <typename scalar_t>
struct ExpBits;
template <>
struct ExpBits<float> {
    using int_t = int32_t;
    static constexpr int degree = 7, mantissa = 23, bias = 127;
};
template <>
struct ExpBits<double> {
    using int_t = int64_t;
    static constexpr int degree = 13, mantissa = 52, bias = 1023;
};

template <typename scalar_t>
inline scalar_t vexp(scalar_t x) {
    using B = ExpBits<scalar_t>;
    x = x >= (scalar_t)-80 ? x : (scalar_t)-80;  // also NaN
    x = x <= (scalar_t)80 ? x : (scalar_t)80;
    // round to nearest by adding and removing 1.5 * 2^mantissa (std::floor would not vectorise)
    constexpr scalar_t shifter = (scalar_t)1.5 * (scalar_t)(1LL << B::mantissa);
    const scalar_t n = (x * (scalar_t)1.4426950408889634 + shifter) - shifter;
    const scalar_t r = (x - n * (scalar_t)0.693145751953125) - n * (scalar_t)1.428606820309417e-06;
    scalar_t p = 1;
#pragma GCC unroll 16
    for (int k = B::degree; k >= 1; --k) p = (scalar_t)1 + r * p * (scalar_t)(1.0 / k);
    const typename B::int_t bits = ((typename B::int_t)n + B::bias) << B::mantissa;
    scalar_t scale;
    std::memcpy(&scale, &bits, sizeof(scale));
    return p * scale;
}

// sigma beyond which alpha is surely below 1/255 (with a margin, so the exact test decides
// near the threshold).
template <typename scalar_t>
std::vector<scalar_t> sigma_cutoffs(const scalar_t* o, int64_t n) {
    std::vector<scalar_t> cut(n);
    for (int64_t g = 0; g < n; ++g) cut[g] = std::log((double)o[g] / ALPHA_MIN) + 1e-3;
    return cut;
}

// One tile's list entry: the Gaussian's 2D parameters, and the rows and lanes (columns) of the
// tile its conservative footprint reaches: the ellipse sigma <= K, K exceeding the cutoff by a
// margin (1% + 0.01), bounded in double. Pixels outside it have sigma beyond the cutoff, so the
// per-pixel test would reject them anyway; a conic that is not positive definite reaches every
// pixel. The lanes are the half of a row [lo, lo + HALF) when the footprint lies within one,
// else all of them: half the vector work, the same result (a trained model's Gaussians span
// 5-6 pixels of a row).
constexpr int32_t HALF = LANES / 2;

template <typename scalar_t>
struct Entry {
    scalar_t mx, my, a, b, c, o, cut;
    int64_t g, ylo, yhi;  // ylo > yhi: no row
    int32_t lo, lanes;    // lanes 0: no pixel
};

template <typename scalar_t>
void tile_entries(const scalar_t* m, const scalar_t* c, const scalar_t* o, const scalar_t* cut, const int64_t* ids,
                  int64_t begin, int64_t end, int64_t x0, int64_t tw, int64_t y0, int64_t y1,
                  std::vector<Entry<scalar_t>>& out) {
    out.resize(end - begin);
    for (int64_t k = begin; k < end; ++k) {
        const int64_t g = ids[k];
        if (k + AHEAD < end) {
            const int64_t ga = ids[k + AHEAD];
            __builtin_prefetch(m + 2 * ga);
            __builtin_prefetch(c + 3 * ga);
            __builtin_prefetch(o + ga);
            __builtin_prefetch(cut + ga);
        }
        auto& e = out[k - begin];
        e = {m[2 * g], m[2 * g + 1], c[3 * g], c[3 * g + 1], c[3 * g + 2], o[g], cut[g], g, y0, y1 - 1, 0, LANES};
        const double a = e.a, b = e.b, cc = e.c, my = e.my, det = a * cc - b * b;
        if (!(a > 0 && det > 0 && std::isfinite(det) && std::isfinite((double)e.mx) && std::isfinite(my))) continue;
        const double K = std::max((double)e.cut, 0.0) * 1.01 + 0.01;
        const double ext = std::sqrt(2 * K * a / det), ext_x = std::sqrt(2 * K * cc / det);
        e.ylo = std::max(y0, (int64_t)std::ceil(my - ext - 0.5 - 1e-3));
        e.yhi = std::min(y1 - 1, (int64_t)std::floor(my + ext - 0.5 + 1e-3));
        const double centre = (double)e.mx - (double)x0 - 0.5;  // in lanes
        const double first = std::max(std::ceil(centre - ext_x - 1e-3), 0.0);
        const double last = std::min(std::floor(centre + ext_x + 1e-3), (double)tw - 1);
        e.lanes = first > last ? 0 : last < HALF ? HALF : first >= HALF ? (e.lo = HALF, HALF) : LANES;
    }
}

// row(lanes, py, lo) on each row py of entry e that wanted(py) accepts, its lanes lo .. lo + N - 1
// (N = lanes::value, fixed at compile time so that the row's loops vectorise to that width).
template <typename scalar_t, typename Wanted, typename Row>
inline void each_row(const Entry<scalar_t>& e, Wanted wanted, Row& row) {
    if (e.lanes == HALF) {
        for (int64_t py = e.ylo; py <= e.yhi; ++py)
            if (wanted(py)) row(std::integral_constant<int32_t, HALF>{}, py, e.lo);
    } else if (e.lanes == LANES) {
        for (int64_t py = e.ylo; py <= e.yhi; ++py)
            if (wanted(py)) row(std::integral_constant<int32_t, LANES>{}, py, 0);
    }
}

// One Gaussian against N pixels of a row (x0 + i, py), n of them inside the image: sigma,
// exp(-sigma), alpha and whether the Gaussian may count there (inside the image, sigma in
// [0, cutoff], alpha at least 1/255), computed for all lanes at once.
template <typename scalar_t>
struct RowSplat {
    scalar_t dx[TILE], ex[TILE], alpha[TILE];
    int32_t ok[TILE];
};

template <int32_t N, typename scalar_t>
inline void row_splat(const Entry<scalar_t>& e, int64_t x0, int64_t n, int64_t py, RowSplat<scalar_t>& s) {
    // locals, so that the compiler need not fear the stores below alias the entry
    const scalar_t mx = e.mx, a = e.a, b = e.b, c = e.c, o = e.o, cut = e.cut;
    const scalar_t dy = (scalar_t)py + (scalar_t)0.5 - e.my;
    scalar_t *sdx = s.dx, *sex = s.ex, *salpha = s.alpha;
    int32_t* sok = s.ok;
#pragma omp simd
    for (int32_t i = 0; i < N; ++i) {
        const scalar_t dx = ((scalar_t)x0 + (scalar_t)i) + (scalar_t)0.5 - mx;
        const scalar_t sigma = (scalar_t)0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy;
        const scalar_t ex = vexp(-sigma);
        const scalar_t raw = o * ex;
        const scalar_t alpha = std::min(raw, (scalar_t)ALPHA_MAX);
        sdx[i] = dx;
        sex[i] = ex;
        salpha[i] = alpha;
        sok[i] = i < n && sigma >= 0 && sigma <= cut && alpha >= (scalar_t)ALPHA_MIN ? 1 : 0;
    }
}

}  // namespace

namespace eve3d {

// Tiles in parallel; within a tile the list is walked once, in order, and each entry is
// composited into the rows it reaches, TILE pixels at a time (vectorised). Each pixel sees the
// same entries in the same order with the same arithmetic as a per-pixel loop (with vexp), and
// keeps its own transmittance, stop flag and count of entries consumed.
template <typename scalar_t>
int64_t composite_forward(const scalar_t* m, const scalar_t* c, const scalar_t* o, const scalar_t* f, int64_t C,
                     int64_t V, const int64_t* off, const int64_t* ids, int64_t tiles, int64_t width, int64_t height,
                     scalar_t* img, scalar_t* tf, int32_t* used) {
    constexpr int64_t P = TILE * TILE;
    const int64_t tiles_x = (width + TILE - 1) / TILE;
    const auto cut = sigma_cutoffs(o, V);
    int64_t n_pairs = 0;
#pragma omp parallel reduction(+ : n_pairs)
    {
        std::vector<Entry<scalar_t>> entries;
        std::vector<scalar_t> acc(C * P);
        RowSplat<scalar_t> s;
#pragma omp for schedule(dynamic)
        for (int64_t t = 0; t < tiles; ++t) {
            const int64_t x0 = (t % tiles_x) * TILE, y0 = (t / tiles_x) * TILE;
            const int64_t tw = std::min(TILE, width - x0), th = std::min(TILE, height - y0);
            tile_entries(m, c, o, cut.data(), ids, off[t], off[t + 1], x0, tw, y0, y0 + th, entries);
            scalar_t T[P];
            int32_t last[P], done[P];
            int64_t row_live[TILE];
            for (int64_t i = 0; i < P; ++i) T[i] = 1, last[i] = 0, done[i] = 0;
            for (int64_t r = 0; r < TILE; ++r) row_live[r] = r < th ? tw : 0;
            std::fill(acc.begin(), acc.end(), (scalar_t)0);
            int64_t live = tw * th;
            for (int64_t j = 0; j < (int64_t)entries.size() && live > 0; ++j) {
                const auto& e = entries[j];
                const scalar_t* fg = f + e.g * C;
                if (j + AHEAD < (int64_t)entries.size()) __builtin_prefetch(f + entries[j + AHEAD].g * C);
                // row py's lanes lo .. lo + N - 1
                auto composite_row = [&](auto lanes_tag, int64_t py, int32_t lo) {
                    constexpr int32_t N = decltype(lanes_tag)::value;
                    const int64_t r = py - y0, q0 = r * TILE + lo;
                    row_splat<N>(e, x0 + lo, tw - lo, py, s);
                    scalar_t* Tr = T + q0;
                    int32_t *dr = done + q0, *lr = last + q0;
                    scalar_t w[N];
                    const int32_t jj = (int32_t)(j + 1);
                    int32_t ended = 0, added = 0;
#pragma omp simd reduction(+ : ended, added)
                    for (int32_t i = 0; i < N; ++i) {
                        const int32_t ok = s.ok[i] & (1 - dr[i]);
                        const scalar_t next_t = Tr[i] * (1 - s.alpha[i]);
                        const int32_t end = ok & (next_t <= (scalar_t)T_MIN ? 1 : 0);
                        const int32_t use = ok & (1 - end);
                        w[i] = use ? s.alpha[i] * Tr[i] : (scalar_t)0;
                        Tr[i] = use ? next_t : Tr[i];
                        lr[i] = use ? jj : lr[i];
                        dr[i] |= end;
                        ended += end;
                        added += use;
                    }
                    if (added)
                        for (int64_t ch = 0; ch < C; ++ch) {
                            scalar_t* a = acc.data() + ch * P + q0;
#pragma omp simd
                            for (int32_t i = 0; i < N; ++i) a[i] += w[i] * fg[ch];
                        }
                    row_live[r] -= ended;
                    live -= ended;
                    n_pairs += added;
                };
                each_row(e, [&](int64_t py) { return row_live[py - y0] > 0; }, composite_row);
            }
            for (int64_t r = 0; r < th; ++r)
                for (int64_t i = 0; i < tw; ++i) {
                    const int64_t p = (y0 + r) * width + x0 + i, q = r * TILE + i;
                    for (int64_t ch = 0; ch < C; ++ch) img[p * C + ch] = acc[ch * P + q];
                    tf[p] = T[q];
                    used[p] = last[q];
                }
        }
    }
    return n_pairs;
}

// The list walked back to front, tile by tile; each pixel recovers the transmittance in front
// of an entry by division (as gsplat does) and the entry's gradient is summed over the tile's
// pixels in lanes, then added once into this thread's buffer.
template <typename scalar_t>
void composite_backward(const scalar_t* m, const scalar_t* c, const scalar_t* o, const scalar_t* f, int64_t C,
                   int64_t V, const int64_t* off, const int64_t* gids, int64_t tiles, int64_t width,
                   int64_t height, const scalar_t* tf, const int32_t* used, const scalar_t* gi,
                   const scalar_t* ga, scalar_t* all) {
    constexpr int64_t P = TILE * TILE;
    const int64_t K = 8 + C;  // per Gaussian: mean2d (2), conic (3), opacity, features (C), |mean2d| (2)
    const int64_t tiles_x = (width + TILE - 1) / TILE;
    const auto cut = sigma_cutoffs(o, V);
#pragma omp parallel
    {
        std::vector<Entry<scalar_t>> entries;
        std::vector<scalar_t> grad(C * P), lanes(K * TILE);
        RowSplat<scalar_t> s;
        scalar_t* buf = all + (int64_t)thread_id() * V * K;
#pragma omp for schedule(dynamic)
        for (int64_t t = 0; t < tiles; ++t) {
            const int64_t x0 = (t % tiles_x) * TILE, y0 = (t / tiles_x) * TILE;
            const int64_t tw = std::min(TILE, width - x0), th = std::min(TILE, height - y0);
            tile_entries(m, c, o, cut.data(), gids, off[t], off[t + 1], x0, tw, y0, y0 + th, entries);
            scalar_t T[P], behind[P], g_alpha[P];
            int32_t count[P];
            int64_t row_max[TILE], kmax = 0;
            std::fill(grad.begin(), grad.end(), (scalar_t)0);
            for (int64_t r = 0; r < TILE; ++r) {
                row_max[r] = 0;
                for (int64_t i = 0; i < TILE; ++i) {
                    const int64_t q = r * TILE + i, p = (y0 + r) * width + x0 + i;
                    const bool in = r < th && i < tw;
                    T[q] = in ? tf[p] : 1;
                    behind[q] = 0;
                    count[q] = in ? used[p] : 0;
                    g_alpha[q] = in ? ga[p] : 0;
                    for (int64_t ch = 0; ch < C; ++ch) grad[ch * P + q] = in ? gi[p * C + ch] : 0;
                    row_max[r] = std::max(row_max[r], (int64_t)count[q]);
                }
                kmax = std::max(kmax, row_max[r]);
            }
            for (int64_t j = kmax - 1; j >= 0; --j) {
                const auto& e = entries[j];
                const scalar_t* fg = f + e.g * C;
                if (j >= AHEAD) {  // Gaussians come in depth order, scattered in memory
                    const int64_t g = entries[j - AHEAD].g;
                    __builtin_prefetch(f + g * C);
                    __builtin_prefetch(buf + g * K, 1);
                    __builtin_prefetch(buf + g * K + K - 1, 1);
                }
                bool any = false;
                // row py's lanes lo .. lo + N - 1
                auto gradient_row = [&](auto lanes_tag, int64_t py, int32_t lo) {
                    constexpr int32_t N = decltype(lanes_tag)::value;
                    const int64_t r = py - y0, q0 = r * TILE + lo;
                    row_splat<N>(e, x0 + lo, tw - lo, py, s);
                    scalar_t *Tr = T + q0, *br = behind + q0;
                    const int32_t* cr = count + q0;
                    scalar_t w[N], dl_dw[N];
                    int32_t ok[N];
                    const int32_t jj = (int32_t)j;
                    int32_t n_ok = 0;
#pragma omp simd reduction(+ : n_ok)
                    for (int32_t i = 0; i < N; ++i) {
                        ok[i] = s.ok[i] & (jj < cr[i] ? 1 : 0);
                        Tr[i] = ok[i] ? Tr[i] / (1 - s.alpha[i]) : Tr[i];  // transmittance in front of g
                        w[i] = ok[i] ? s.alpha[i] * Tr[i] : (scalar_t)0;
                        dl_dw[i] = g_alpha[q0 + i];
                        n_ok += ok[i];
                    }
                    if (!n_ok) return;
                    if (!any) {
                        std::fill(lanes.begin(), lanes.end(), (scalar_t)0);
                        any = true;
                    }
                    for (int64_t ch = 0; ch < C; ++ch) {
                        const scalar_t* G = grad.data() + ch * P + q0;
                        scalar_t* L = lanes.data() + (6 + ch) * TILE + lo;
#pragma omp simd
                        for (int32_t i = 0; i < N; ++i) {
                            dl_dw[i] += G[i] * fg[ch];
                            L[i] += w[i] * G[i];
                        }
                    }
                    scalar_t* L = lanes.data() + lo;
                    const scalar_t dy = (scalar_t)py + (scalar_t)0.5 - e.my;
#pragma omp simd
                    for (int32_t i = 0; i < N; ++i) {
                        const scalar_t one_minus = 1 - s.alpha[i];
                        scalar_t dl_dalpha = Tr[i] * dl_dw[i] - br[i] / one_minus;
                        br[i] += w[i] * dl_dw[i];
                        const scalar_t raw = e.o * s.ex[i];
                        dl_dalpha = raw > (scalar_t)ALPHA_MAX ? (scalar_t)0 : dl_dalpha;  // clamped: flat
                        dl_dalpha = ok[i] ? dl_dalpha : (scalar_t)0;
                        const scalar_t dl_dsigma = -dl_dalpha * raw;
                        const scalar_t dx = s.dx[i];
                        // selected, not multiplied: a masked-out lane's terms may be NaN
                        const scalar_t dmx = ok[i] ? -dl_dsigma * (e.a * dx + e.b * dy) : (scalar_t)0;
                        const scalar_t dmy = ok[i] ? -dl_dsigma * (e.b * dx + e.c * dy) : (scalar_t)0;
                        L[i] += dmx;
                        L[TILE + i] += dmy;
                        L[2 * TILE + i] += (scalar_t)0.5 * dl_dsigma * dx * dx;
                        L[3 * TILE + i] += dl_dsigma * dx * dy;
                        L[4 * TILE + i] += (scalar_t)0.5 * dl_dsigma * dy * dy;
                        L[5 * TILE + i] += dl_dalpha * s.ex[i];
                        L[(6 + C) * TILE + i] += std::abs(dmx);
                        L[(7 + C) * TILE + i] += std::abs(dmy);
                    }
                };
                each_row(e, [&](int64_t py) { return j < row_max[py - y0]; }, gradient_row);
                if (any) {  // the lanes that ran (the others hold 0)
                    scalar_t* b = buf + e.g * K;
                    for (int64_t q = 0; q < K; ++q) {
                        scalar_t sum = 0;
                        for (int64_t i = e.lo; i < e.lo + e.lanes; ++i) sum += lanes[q * TILE + i];
                        b[q] += sum;
                    }
                }
            }
        }
    }
}

template int64_t composite_forward<float>(const float*, const float*, const float*, const float*, int64_t, int64_t,
                                          const int64_t*, const int64_t*, int64_t, int64_t, int64_t, float*, float*,
                                          int32_t*);
template int64_t composite_forward<double>(const double*, const double*, const double*, const double*, int64_t,
                                           int64_t, const int64_t*, const int64_t*, int64_t, int64_t, int64_t,
                                           double*, double*, int32_t*);
template void composite_backward<float>(const float*, const float*, const float*, const float*, int64_t, int64_t,
                                        const int64_t*, const int64_t*, int64_t, int64_t, int64_t, const float*,
                                        const int32_t*, const float*, const float*, float*);
template void composite_backward<double>(const double*, const double*, const double*, const double*, int64_t,
                                         int64_t, const int64_t*, const int64_t*, int64_t, int64_t, int64_t,
                                         const double*, const int32_t*, const double*, const double*, double*);

}  // namespace eve3d

namespace {

// Stable LSD radix sort of indices by key (unsigned integers ordered as the values are).
template <typename key_t>
void radix_sort(std::vector<key_t>& keys, std::vector<int64_t>& idx) {
    const size_t n = keys.size();
    std::vector<key_t> k2(n);
    std::vector<int64_t> i2(n);
    for (int shift = 0; shift < (int)(8 * sizeof(key_t)); shift += 8) {
        size_t count[257] = {0};
        for (size_t i = 0; i < n; ++i) count[((keys[i] >> shift) & 0xff) + 1]++;
        if (count[((keys[0] >> shift) & 0xff) + 1] == n) continue;  // one bucket: order unchanged
        for (int b = 0; b < 256; ++b) count[b + 1] += count[b];
        for (size_t i = 0; i < n; ++i) {
            const size_t d = count[(keys[i] >> shift) & 0xff]++;
            k2[d] = keys[i];
            i2[d] = idx[i];
        }
        keys.swap(k2);
        idx.swap(i2);
    }
}

template <typename scalar_t, typename key_t>
void sort_by_depth(const scalar_t* depths, std::vector<int64_t>& idx) {
    if (idx.empty()) return;
    std::vector<key_t> keys(idx.size());
    for (size_t i = 0; i < idx.size(); ++i) {
        key_t bits;
        std::memcpy(&bits, depths + idx[i], sizeof(key_t));
        const key_t sign = (key_t)1 << (8 * sizeof(key_t) - 1);
        keys[i] = (bits & sign) ? ~bits : (bits | sign);  // float order (-0 before +0; no NaN here)
    }
    radix_sort(keys, idx);
}

}  // namespace

namespace eve3d {

template <typename scalar_t>
void front_to_back(const int32_t* r, const scalar_t* depths, const scalar_t* m, int64_t n, int64_t width,
                   int64_t height, std::vector<int64_t>& idx, std::vector<int64_t>& boxes) {
    idx.clear();
    idx.reserve(n);
    for (int64_t i = 0; i < n; ++i)
        if (r[2 * i] > 0 || r[2 * i + 1] > 0) idx.push_back(i);
    if (sizeof(scalar_t) == 4)
        sort_by_depth<scalar_t, uint32_t>(depths, idx);
    else
        sort_by_depth<scalar_t, uint64_t>(depths, idx);
    const int64_t v = idx.size();
    boxes.resize(4 * v);
    int64_t* b = boxes.data();
    const scalar_t half = (scalar_t)0.5, big = (scalar_t)1e12;
    const scalar_t limit[2] = {(scalar_t)(width - 1), (scalar_t)(height - 1)};
    for (int64_t j = 0; j < v; ++j) {
        for (int a = 0; a < 2; ++a) {
            const scalar_t mm = m[2 * idx[j] + a], rr = (scalar_t)r[2 * idx[j] + a];
            scalar_t lo = std::ceil(mm - rr - half);
            lo = lo < 0 ? (scalar_t)0 : lo;
            scalar_t hi = std::floor(mm + rr - half);
            hi = hi < limit[a] ? hi : limit[a];
            b[4 * j + a] = (int64_t)std::min(lo, big);
            b[4 * j + 2 + a] = (int64_t)std::max(hi, -big);
        }
    }
}

template void front_to_back<float>(const int32_t*, const float*, const float*, int64_t, int64_t, int64_t,
                                   std::vector<int64_t>&, std::vector<int64_t>&);
template void front_to_back<double>(const int32_t*, const double*, const double*, int64_t, int64_t, int64_t,
                                    std::vector<int64_t>&, std::vector<int64_t>&);

}  // namespace eve3d
