#include "util/threads.h"

#include <ATen/Parallel.h>
#include <omp.h>
#include <opencv2/core.hpp>

#include <cstdlib>
#include <thread>

namespace refocus {

int init_threads() {
    int n = static_cast<int>(std::thread::hardware_concurrency());
    if (const char* env = std::getenv("REFOCUS_THREADS")) {
        int v = std::atoi(env);
        if (v > 0) n = v;
    }
    if (n < 1) n = 1;
    at::set_num_threads(n);
    omp_set_num_threads(n);
    cv::setNumThreads(n);
    return n;
}

}  // namespace refocus
