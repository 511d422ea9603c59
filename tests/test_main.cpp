#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include "util/allocator.h"
#include "util/threads.h"

int main(int argc, char** argv) {
    refocus::tune_allocator();
    refocus::init_threads();
    doctest::Context ctx;
    ctx.applyCommandLine(argc, argv);
    return ctx.run();
}
