// Tile-based Gaussian compositing on the CPU (forward and backward), gsplat's rules:
// alpha = min(0.999, o * exp(-sigma)); skip alpha < 1/255 or sigma < 0; stop before the
// Gaussian that would take the transmittance T to <= 1e-4; pixel centres at +0.5.
// Gaussians arrive sorted front to back, so binning them in order keeps every tile's list
// depth-sorted. The backward pass walks each pixel's list back to front, recovering T by
// division as gsplat does, and accumulates gradients in per-thread buffers.
#include <torch/extension.h>

#include "projection.h"
#include "roundtrip.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace {

constexpr int64_t TILE = 16;
constexpr double ALPHA_MIN = 1.0 / 255.0;
constexpr double ALPHA_MAX = 0.999;
constexpr double T_MIN = 1e-4;

int max_threads() {
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

int thread_id() {
#ifdef _OPENMP
    return omp_get_thread_num();
#else
    return 0;
#endif
}

// Per-tile lists of Gaussian indices (CSR): offsets (tiles + 1) and ids. boxes (V, 4) belong to
// the visible Gaussians in depth order; ids are their indices among all N (visible[rank]).
std::vector<torch::Tensor> bin_tiles(const torch::Tensor& boxes, const torch::Tensor& visible, int64_t width,
                                     int64_t height) {
    const int64_t tiles_x = (width + TILE - 1) / TILE, tiles_y = (height + TILE - 1) / TILE;
    const int64_t n = boxes.size(0);
    auto b = boxes.accessor<int64_t, 2>();
    const auto vis_c = visible.contiguous();
    const int64_t* vis = vis_c.data_ptr<int64_t>();
    std::vector<int64_t> counts(tiles_x * tiles_y + 1, 0);
    for (int64_t g = 0; g < n; ++g) {
        if (b[g][2] < b[g][0] || b[g][3] < b[g][1]) continue;
        for (int64_t ty = b[g][1] / TILE; ty <= b[g][3] / TILE; ++ty)
            for (int64_t tx = b[g][0] / TILE; tx <= b[g][2] / TILE; ++tx) counts[ty * tiles_x + tx + 1]++;
    }
    for (size_t i = 1; i < counts.size(); ++i) counts[i] += counts[i - 1];
    auto offsets = torch::from_blob(counts.data(), {(int64_t)counts.size()}, torch::kInt64).clone();
    auto ids = torch::empty({counts.back()}, torch::kInt64);
    int64_t* out = ids.data_ptr<int64_t>();
    std::vector<int64_t> fill(counts.begin(), counts.end() - 1);
    for (int64_t g = 0; g < n; ++g) {
        if (b[g][2] < b[g][0] || b[g][3] < b[g][1]) continue;
        for (int64_t ty = b[g][1] / TILE; ty <= b[g][3] / TILE; ++ty)
            for (int64_t tx = b[g][0] / TILE; tx <= b[g][2] / TILE; ++tx) out[fill[ty * tiles_x + tx]++] = vis[g];
    }
    return {offsets, ids};
}

template <typename scalar_t>
struct Splat {
    scalar_t alpha, raw, dx, dy;
    bool skip;
};

// sigma beyond which alpha is surely below 1/255 (with a margin, so the exact test decides
// near the threshold): skips most of exp() for the tile's Gaussians a pixel does not see.
template <typename scalar_t>
std::vector<scalar_t> sigma_cutoffs(const scalar_t* o, int64_t n) {
    std::vector<scalar_t> cut(n);
    for (int64_t g = 0; g < n; ++g) cut[g] = std::log((double)o[g] / ALPHA_MIN) + 1e-3;
    return cut;
}

template <typename scalar_t>
inline Splat<scalar_t> splat(const scalar_t* m, const scalar_t* c, const scalar_t* o, const scalar_t* cut,
                             int64_t g, int64_t px, int64_t py) {
    Splat<scalar_t> s;
    s.dx = (scalar_t)px + (scalar_t)0.5 - m[2 * g];
    s.dy = (scalar_t)py + (scalar_t)0.5 - m[2 * g + 1];
    const scalar_t sigma =
        (scalar_t)0.5 * (c[3 * g] * s.dx * s.dx + c[3 * g + 2] * s.dy * s.dy) + c[3 * g + 1] * s.dx * s.dy;
    if (sigma < 0 || sigma > cut[g]) {
        s.skip = true;
        return s;
    }
    s.raw = o[g] * std::exp(-sigma);
    s.alpha = std::min(s.raw, (scalar_t)ALPHA_MAX);
    s.skip = s.alpha < (scalar_t)ALPHA_MIN;
    return s;
}

// One tile's list entry with the conservative footprint used to skip pixels: the ellipse
// sigma <= K, where K exceeds the cutoff by a margin (1% + 0.01), in double. Every pixel
// whose centre lies outside it has sigma beyond the cutoff, so the exact
// per-pixel test would skip it anyway; inside, the per-pixel test decides as before.
struct Entry {
    double mx, my, a, b, c, K;
    int64_t ylo, yhi;  // rows of the tile that may see it (inclusive; empty when ylo > yhi)
    bool full;         // conic not positive definite: test every pixel
};

template <typename scalar_t>
void tile_entries(const scalar_t* m, const scalar_t* c, const scalar_t* cut, const int64_t* ids, int64_t begin,
                  int64_t end, int64_t y0, int64_t y1, std::vector<Entry>& out) {
    out.resize(end - begin);
    for (int64_t k = begin; k < end; ++k) {
        const int64_t g = ids[k];
        Entry& e = out[k - begin];
        e.mx = m[2 * g];
        e.my = m[2 * g + 1];
        e.a = c[3 * g];
        e.b = c[3 * g + 1];
        e.c = c[3 * g + 2];
        e.K = std::max((double)cut[g], 0.0) * 1.01 + 0.01;
        const double det = e.a * e.c - e.b * e.b;
        e.full = !(e.a > 0 && det > 0 && std::isfinite(det) && std::isfinite(e.mx) && std::isfinite(e.my));
        if (e.full) {
            e.ylo = y0;
            e.yhi = y1 - 1;
            continue;
        }
        const double ext = std::sqrt(2 * e.K * e.a / det);
        e.ylo = std::max(y0, (int64_t)std::ceil(e.my - ext - 0.5 - 1e-3));
        e.yhi = std::min(y1 - 1, (int64_t)std::floor(e.my + ext - 0.5 + 1e-3));
    }
}

// Columns [x_lo, x_hi] of row py that may see entry e, clipped to [x0, x1); false if none.
inline bool row_span(const Entry& e, int64_t py, int64_t x0, int64_t x1, int64_t& x_lo, int64_t& x_hi) {
    if (py < e.ylo || py > e.yhi) return false;
    if (e.full) {
        x_lo = x0;
        x_hi = x1 - 1;
        return true;
    }
    const double dy = py + 0.5 - e.my;
    const double disc = e.b * e.b * dy * dy - e.a * (e.c * dy * dy - 2 * e.K);
    if (!(disc >= 0)) return false;
    const double sq = std::sqrt(disc);
    x_lo = std::max(x0, (int64_t)std::ceil(e.mx + (-e.b * dy - sq) / e.a - 0.5 - 1e-3));
    x_hi = std::min(x1 - 1, (int64_t)std::floor(e.mx + (-e.b * dy + sq) / e.a - 0.5 + 1e-3));
    return x_lo <= x_hi;
}

// Each pixel still takes its tile's list in order with the same arithmetic as a plain
// per-pixel loop; a row of the tile walks the list together, so that an entry's footprint
// is computed once per row and only the pixels it may cover are tested.
template <typename scalar_t>
int64_t forward_impl(const scalar_t* m, const scalar_t* c, const scalar_t* o, const scalar_t* f, int64_t C,
                     int64_t V, const int64_t* off, const int64_t* ids, int64_t tiles, int64_t width, int64_t height,
                     scalar_t* img, scalar_t* tf, int32_t* used) {
    const int64_t tiles_x = (width + TILE - 1) / TILE;
    const auto cut = sigma_cutoffs(o, V);
    int64_t n_pairs = 0;
#pragma omp parallel reduction(+ : n_pairs)
    {
        std::vector<Entry> entries;
#pragma omp for schedule(dynamic)
        for (int64_t t = 0; t < tiles; ++t) {
            const int64_t x0 = (t % tiles_x) * TILE, y0 = (t / tiles_x) * TILE;
            const int64_t x1 = std::min(x0 + TILE, width), y1 = std::min(y0 + TILE, height);
            tile_entries(m, c, cut.data(), ids, off[t], off[t + 1], y0, y1, entries);
            const int64_t n = off[t + 1] - off[t];
            for (int64_t py = y0; py < y1; ++py) {
                scalar_t T[TILE];
                int32_t last[TILE];
                bool done[TILE];
                for (int64_t i = 0; i < TILE; ++i) T[i] = 1, last[i] = 0, done[i] = false;
                int64_t live = x1 - x0;
                for (int64_t j = 0; j < n && live > 0; ++j) {
                    int64_t xa, xb;
                    if (!row_span(entries[j], py, x0, x1, xa, xb)) continue;
                    const int64_t g = ids[off[t] + j];
                    for (int64_t px = xa; px <= xb; ++px) {
                        const int64_t i = px - x0;
                        if (done[i]) continue;
                        const auto s = splat(m, c, o, cut.data(), g, px, py);
                        if (s.skip) continue;
                        const scalar_t next_t = T[i] * (1 - s.alpha);
                        if (next_t <= (scalar_t)T_MIN) {
                            done[i] = true;
                            --live;
                            continue;
                        }
                        const scalar_t w = s.alpha * T[i];
                        const int64_t p = py * width + px;
                        for (int64_t ch = 0; ch < C; ++ch) img[p * C + ch] += w * f[g * C + ch];
                        T[i] = next_t;
                        last[i] = (int32_t)(j + 1);
                        ++n_pairs;
                    }
                }
                for (int64_t px = x0; px < x1; ++px) {
                    tf[py * width + px] = T[px - x0];
                    used[py * width + px] = last[px - x0];
                }
            }
        }
    }
    return n_pairs;
}

template <typename scalar_t>
void backward_impl(const scalar_t* m, const scalar_t* c, const scalar_t* o, const scalar_t* f, int64_t C,
                   int64_t V, const int64_t* off, const int64_t* gids, int64_t tiles, int64_t width,
                   int64_t height, const scalar_t* tf, const int32_t* used, const scalar_t* gi,
                   const scalar_t* ga, scalar_t* all) {
    const int64_t K = 8 + C;  // per Gaussian: mean2d (2), conic (3), opacity, features (C), |mean2d| (2)
    const int64_t tiles_x = (width + TILE - 1) / TILE;
    const auto cut = sigma_cutoffs(o, V);
#pragma omp parallel
    {
        std::vector<Entry> entries;
        std::vector<scalar_t> acc(K);
        scalar_t* buf = all + (int64_t)thread_id() * V * K;
#pragma omp for schedule(dynamic)
        for (int64_t t = 0; t < tiles; ++t) {
            const int64_t x0 = (t % tiles_x) * TILE, y0 = (t / tiles_x) * TILE;
            const int64_t x1 = std::min(x0 + TILE, width), y1 = std::min(y0 + TILE, height);
            tile_entries(m, c, cut.data(), gids, off[t], off[t + 1], y0, y1, entries);
            for (int64_t py = y0; py < y1; ++py) {
                scalar_t T[TILE], behind[TILE];
                int64_t kmax = 0;
                for (int64_t px = x0; px < x1; ++px) {
                    T[px - x0] = tf[py * width + px];
                    behind[px - x0] = 0;
                    kmax = std::max(kmax, (int64_t)used[py * width + px]);
                }
                for (int64_t j = kmax - 1; j >= 0; --j) {
                    int64_t xa, xb;
                    if (!row_span(entries[j], py, x0, x1, xa, xb)) continue;
                    const int64_t g = gids[off[t] + j];
                    bool any = false;
                    for (int64_t px = xa; px <= xb; ++px) {
                        const int64_t p = py * width + px;
                        if (j >= used[p]) continue;
                        const auto s = splat(m, c, o, cut.data(), g, px, py);
                        if (s.skip) continue;
                        const int64_t i = px - x0;
                        const scalar_t* G = gi + p * C;
                        T[i] /= 1 - s.alpha;  // transmittance in front of g
                        const scalar_t w = s.alpha * T[i];
                        scalar_t dl_dw = ga[p];
                        for (int64_t ch = 0; ch < C; ++ch) dl_dw += G[ch] * f[g * C + ch];
                        scalar_t dl_dalpha = T[i] * dl_dw - behind[i] / (1 - s.alpha);
                        behind[i] += w * dl_dw;
                        if (s.raw > (scalar_t)ALPHA_MAX) dl_dalpha = 0;  // clamped: flat
                        const scalar_t dl_dsigma = -dl_dalpha * s.raw;
                        const scalar_t dmx = -dl_dsigma * (c[3 * g] * s.dx + c[3 * g + 1] * s.dy);
                        const scalar_t dmy = -dl_dsigma * (c[3 * g + 1] * s.dx + c[3 * g + 2] * s.dy);
                        if (!any) {
                            std::fill(acc.begin(), acc.end(), (scalar_t)0);
                            any = true;
                        }
                        acc[0] += dmx;
                        acc[1] += dmy;
                        acc[2] += (scalar_t)0.5 * dl_dsigma * s.dx * s.dx;
                        acc[3] += dl_dsigma * s.dx * s.dy;
                        acc[4] += (scalar_t)0.5 * dl_dsigma * s.dy * s.dy;
                        acc[5] += dl_dalpha * s.raw / o[g];
                        for (int64_t ch = 0; ch < C; ++ch) acc[6 + ch] += w * G[ch];
                        acc[6 + C] += std::abs(dmx);
                        acc[7 + C] += std::abs(dmy);
                    }
                    if (any) {
                        scalar_t* b = buf + g * K;
                        for (int64_t q = 0; q < K; ++q) b[q] += acc[q];
                    }
                }
            }
        }
    }
}

}  // namespace

// Returns image (H*W, C), final transmittance (H*W), per-pixel count of list entries
// consumed (H*W, int32), tile offsets, tile ids and the number of pairs composited.
std::vector<torch::Tensor> forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                   torch::Tensor feats, torch::Tensor boxes, torch::Tensor visible, int64_t width,
                                   int64_t height) {
    auto bins = bin_tiles(boxes, visible, width, height);
    auto image = torch::zeros({height * width, feats.size(1)}, feats.options());
    auto final_t = torch::ones({height * width}, feats.options());
    auto consumed = torch::zeros({height * width}, torch::kInt32);
    int64_t n_pairs = 0;
    AT_DISPATCH_FLOATING_TYPES(feats.scalar_type(), "eve3d_rasterize_forward", [&] {
        n_pairs = forward_impl<scalar_t>(
            means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), opac.data_ptr<scalar_t>(),
            feats.data_ptr<scalar_t>(), feats.size(1), feats.size(0), bins[0].data_ptr<int64_t>(), bins[1].data_ptr<int64_t>(),
            bins[0].size(0) - 1, width, height, image.data_ptr<scalar_t>(), final_t.data_ptr<scalar_t>(),
            consumed.data_ptr<int32_t>());
    });
    return {image, final_t, consumed, bins[0], bins[1], torch::tensor(n_pairs)};
}

// Gradients for means2d (V, 2), conics (V, 3), opacities (V), features (V, C) and the
// per-pixel absolute means2d gradients summed per Gaussian (V, 2).
std::vector<torch::Tensor> backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opac,
                                    torch::Tensor feats, torch::Tensor offsets, torch::Tensor ids,
                                    torch::Tensor final_t, torch::Tensor consumed, torch::Tensor grad_image,
                                    torch::Tensor grad_alpha, int64_t width, int64_t height) {
    const int64_t C = feats.size(1), V = feats.size(0);
    auto buffers = torch::zeros({max_threads(), V, 8 + C}, feats.options());
    AT_DISPATCH_FLOATING_TYPES(feats.scalar_type(), "eve3d_rasterize_backward", [&] {
        backward_impl<scalar_t>(
            means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(), opac.data_ptr<scalar_t>(),
            feats.data_ptr<scalar_t>(), C, V, offsets.data_ptr<int64_t>(), ids.data_ptr<int64_t>(),
            offsets.size(0) - 1, width, height, final_t.data_ptr<scalar_t>(), consumed.data_ptr<int32_t>(),
            grad_image.data_ptr<scalar_t>(), grad_alpha.data_ptr<scalar_t>(), buffers.data_ptr<scalar_t>());
    });
    auto total = buffers.sum(0);
    return {total.slice(1, 0, 2), total.slice(1, 2, 5), total.select(1, 5), total.slice(1, 6, 6 + C),
            total.slice(1, 6 + C, 8 + C)};
}

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

// eve3d.render.projection.front_to_back in C++: the Gaussians with a positive radius, sorted
// stably by depth, and their inclusive pixel boxes (V, 4) x0, y0, x1, y1, computed with the
// same float operations.
std::vector<torch::Tensor> front_to_back(torch::Tensor radii, torch::Tensor depths, torch::Tensor means2d,
                                         int64_t width, int64_t height) {
    radii = radii.to(torch::kInt32).contiguous();
    means2d = means2d.contiguous();
    depths = depths.to(means2d.scalar_type()).contiguous();
    const int64_t n = radii.size(0);
    const int32_t* r = radii.data_ptr<int32_t>();
    std::vector<int64_t> idx;
    idx.reserve(n);
    for (int64_t i = 0; i < n; ++i)
        if (r[2 * i] > 0 || r[2 * i + 1] > 0) idx.push_back(i);
    torch::Tensor boxes;
    AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "eve3d_front_to_back", [&] {
        if (sizeof(scalar_t) == 4)
            sort_by_depth<scalar_t, uint32_t>(depths.data_ptr<scalar_t>(), idx);
        else
            sort_by_depth<scalar_t, uint64_t>(depths.data_ptr<scalar_t>(), idx);
        const int64_t v = idx.size();
        boxes = torch::empty({v, 4}, torch::kInt64);
        int64_t* b = boxes.data_ptr<int64_t>();
        const scalar_t* m = means2d.data_ptr<scalar_t>();
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
    });
    auto visible = torch::from_blob(idx.data(), {(int64_t)idx.size()}, torch::kInt64).clone();
    return {visible, boxes};
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    m.def("forward", &forward, "tile-based Gaussian compositing (forward)");
    m.def("backward", &backward, "tile-based Gaussian compositing (backward)");
    m.def("front_to_back", &front_to_back, "visible Gaussians sorted by depth, and their pixel boxes");
    m.def("project_forward", &project_forward, "fused EWA projection and PGSR planes (forward)");
    m.def("project_backward", &project_backward, "fused EWA projection and PGSR planes (backward)");
    m.def("roundtrip_forward", &roundtrip_forward, "PGSR's multi-view round trip against K neighbours (forward)");
    m.def("roundtrip_backward", &roundtrip_backward, "PGSR's multi-view round trip (backward)");
    m.def("ncc_forward", &ncc_forward, "1 - NCC of homography-warped patches against K neighbours (forward)");
    m.def("ncc_backward", &ncc_backward, "1 - NCC of homography-warped patches (backward)");
}
