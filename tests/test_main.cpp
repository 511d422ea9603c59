#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include "util/threads.h"

int main(int argc, char** argv) {
    refocus::init_threads();
    doctest::Context ctx;
    ctx.applyCommandLine(argc, argv);
    return ctx.run();
}
