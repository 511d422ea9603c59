#include "util/threads.h"

#include <ATen/Parallel.h>
#include <c10/core/GradMode.h>
#include <omp.h>
#include <opencv2/core.hpp>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace refocus {

int threads_from_env(const char* env, int cores, std::string* warning) {
    const int n = std::max(1, cores);
    if (!env) return n;
    // More threads than 4 a core only thrash (99999 hung every command): refused with a warning.
    const long hi = 4L * n;
    errno = 0;
    char* end = nullptr;
    const long v = std::strtol(env, &end, 10);
    const bool number = end != env && *end == '\0' && errno == 0;
    if (number && v >= 1 && v <= hi) return static_cast<int>(v);
    if (warning)
        *warning = "warning: REFOCUS_THREADS='" + std::string(env) +
                   "' is not a thread count in 1.." + std::to_string(hi) + " (4 per core); using " +
                   std::to_string(n) + " (the core count)";
    return n;
}

int init_threads() {
    std::string warning;
    const int n = threads_from_env(std::getenv("REFOCUS_THREADS"),
                                   static_cast<int>(std::thread::hardware_concurrency()), &warning);
    if (!warning.empty()) std::fprintf(stderr, "%s\n", warning.c_str());
    at::set_num_threads(n);
    omp_set_num_threads(n);
    cv::setNumThreads(n);
    return n;
}

void for_each_on_threads(int n, int threads, const std::function<void(int, int)>& fn) {
    if (threads <= 0) threads = at::get_num_threads();
    threads = std::max(1, std::min(threads, n));
    std::exception_ptr failed;
    std::mutex lock;
    auto run = [&](int k) {
        try {
            for (int i = k; i < n; i += threads) {
                {
                    std::lock_guard<std::mutex> g(lock);
                    if (failed) return;
                }
                fn(i, k);
            }
        } catch (...) {
            std::lock_guard<std::mutex> g(lock);
            if (!failed) failed = std::current_exception();
        }
    };
    std::vector<std::thread> pool;
    for (int k = 1; k < threads; ++k) pool.emplace_back(run, k);
    run(0);
    for (auto& t : pool) t.join();
    if (failed) std::rethrow_exception(failed);
}

void for_each_in_parts(int64_t n, int parts, const std::function<void(int64_t i, int p)>& fn) {
    const bool grad = c10::GradMode::is_enabled();  // thread-local: the workers take the caller's
    at::parallel_for(0, parts, 1, [&](int64_t p0, int64_t p1) {
        c10::AutoGradMode mode(grad);
        for (int64_t p = p0; p < p1; ++p)
            for (int64_t i = p; i < n; i += parts) fn(i, int(p));
    });
}

}  // namespace refocus
