#include "radius/stack_costs.h"

#include <ATen/Parallel.h>

#include <algorithm>

namespace refocus {

torch::Tensor squared_difference(const torch::Tensor& a_in, const torch::Tensor& b_in) {
    auto a = a_in.contiguous(), b = b_in.contiguous();
    const int64_t C = a.size(0), N = a.size(1) * a.size(2);
    auto out = torch::empty({1, 1, a.size(1), a.size(2)});
    const float *pa = a.data_ptr<float>(), *pb = b.data_ptr<float>();
    float* po = out.data_ptr<float>();
    at::parallel_for(0, N, 16384, [&](int64_t i0, int64_t i1) {
        for (int64_t i = i0; i < i1; ++i) {
            float acc = 0;
            for (int64_t ch = 0; ch < C; ++ch) {
                const float d = pa[ch * N + i] - pb[ch * N + i];
                acc += d * d;
            }
            po[i] = acc;
        }
    });
    return out;
}

void RunningArgmin::add(const torch::Tensor& ck_in, int64_t k) {
    auto ck = ck_in.contiguous();
    if (k == 0) {
        cmin = ck.clone(), cmax = ck.clone(), prev = ck.clone();
        c0 = ck.clone(), c1 = ck.clone(), c2 = ck.clone();
        best = torch::zeros(ck.sizes(), torch::kLong);
        return;
    }
    const float* c = ck.data_ptr<float>();
    float *lo = cmin.data_ptr<float>(), *hi = cmax.data_ptr<float>(), *pv = prev.data_ptr<float>(),
          *p0 = c0.data_ptr<float>(), *p1 = c1.data_ptr<float>(), *p2 = c2.data_ptr<float>();
    int64_t* bi = best.data_ptr<int64_t>();
    at::parallel_for(0, ck.numel(), 16384, [&](int64_t i0, int64_t i1) {
        for (int64_t i = i0; i < i1; ++i) {
            const float v = c[i];
            if (bi[i] == k - 1) p2[i] = v;  // the cost after the argmin so far
            if (v < lo[i]) {                // the first least, as argmin
                p0[i] = pv[i];
                p1[i] = v;
                bi[i] = k;
                lo[i] = v;
            }
            hi[i] = std::max(hi[i], v);
            pv[i] = v;
        }
    });
}

// The update as it was written in tensor ops: the reference `add` is tested against.
void RunningArgmin::add_reference(const torch::Tensor& ck, int64_t k) {
    if (k == 0) {
        cmin = ck.clone(), cmax = ck.clone(), prev = ck.clone();
        c0 = ck.clone(), c1 = ck.clone(), c2 = ck.clone();
        best = torch::zeros(ck.sizes(), torch::kLong);
        return;
    }
    auto lower = ck < cmin;
    c2 = torch::where(best == k - 1, ck, c2);
    c0 = torch::where(lower, prev, c0);
    c1 = torch::where(lower, ck, c1);
    best = torch::where(lower, torch::full_like(best, k), best);
    cmin = torch::minimum(cmin, ck);
    cmax = torch::maximum(cmax, ck);
    prev = ck.clone();
}

}  // namespace refocus
