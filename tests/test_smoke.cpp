#include <doctest/doctest.h>
#include "test_util.h"
TEST_CASE("cli help lists commands") {
    auto r = refocus::test::cli("--help");
    CHECK(r.code == 0);
    CHECK(r.output.find("new") != std::string::npos);
}
