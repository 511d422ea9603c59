// The command line: help, unknown commands and options.
#include <doctest/doctest.h>

#include "test_util.h"

using refocus::test::cli;

TEST_CASE("--help lists the subcommands") {
    auto r = cli("--help");
    CHECK(r.code == 0);
    for (const char* c : {"new", "info"})
        CHECK(r.output.find(std::string("  ") + c) != std::string::npos);
}

TEST_CASE("unknown command and unknown option fail with a message") {
    auto r = cli("frobnicate");
    CHECK(r.code == 2);
    CHECK(r.output.find("unknown command 'frobnicate'") != std::string::npos);
    r = cli("info --frmaes 3 x.mp4");
    CHECK(r.code != 0);
    CHECK(r.output.find("unknown option --frmaes") != std::string::npos);
}
