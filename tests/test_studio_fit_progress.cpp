// The fit's preparation as the studio shows it: its steps reported through PrepareLog's stage
// sink (named, laid out in order over [0, 1]), the worker's estimate while it prepares (never
// backwards, inside [0, 1]), and a budget in minutes that holds the preparation.
// LibTorch (through the worker) first: glog's CHECK must not replace doctest's.
#include "fit/fit_setup.h"
#include "studio/fit_worker.h"
#undef CHECK
#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <thread>

#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

namespace {
struct Step {
    std::string name;
    double begin, end;
};
}  // namespace

TEST_CASE("preparation steps: named, in order, spanning [0, 1]") {
    PrepareLog log;
    std::vector<Step> steps;
    log.set_stage_sink([&](const std::string& n, double b, double e) {
        steps.push_back({n, b, e});
    });
    log.set_span(0.5, 0.7);  // a part's own 0..1 lands inside its span
    log.stage("inner", 0.5, 1.0);
    REQUIRE(steps.size() == 1);
    CHECK(steps[0].begin == doctest::Approx(0.6));
    CHECK(steps[0].end == doctest::Approx(0.7));

    steps.clear();
    const TinyClip c = make_tiny("fit_progress_steps");
    PrepareLog prep;
    prep.set_stage_sink([&](const std::string& n, double b, double e) {
        steps.push_back({n, b, e});
    });
    FitSetupOptions opts;
    opts.force_prepare = true;
    build_fit_data(Project::load(c.project), opts, prep);
    std::vector<std::string> names;
    for (size_t i = 0; i < steps.size(); ++i) {
        names.push_back(steps[i].name);
        CHECK(steps[i].begin >= 0.0);
        CHECK(steps[i].end <= 1.0);
        CHECK(steps[i].begin <= steps[i].end);
        if (i > 0) CHECK(steps[i].begin >= steps[i - 1].end - 1e-9);  // in order, no overlap
    }
    INFO(nlohmann::json(names).dump());
    for (const char* want :
         {"reading the frames", "optical flow", "camera motion", "subject masks", "radius maps"})
        CHECK(std::find(names.begin(), names.end(), want) != names.end());
    // The per-frame radius is a stage only where it is the fit's source (not before a focal
    // stack, as here).
    CHECK(std::find(names.begin(), names.end(), "circle of confusion") == names.end());
}

TEST_CASE("fit worker: preparation progress while preparing, and inside the minutes budget") {
    const TinyClip c = make_tiny("fit_progress_worker");
    FitWorker w;
    w.open(Project::load(c.project));
    auto wait_idle = [&] {
        const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(300);
        while (std::chrono::steady_clock::now() < end) {
            const auto s = w.status();
            if (!s.busy && s.state != FitWorker::State::Preparing &&
                s.state != FitWorker::State::Fitting)
                return true;
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
        return false;
    };
    REQUIRE(wait_idle());

    FitSettings s;
    s.fit.minutes = 0.05;  // 3 s, the preparation included
    s.setup.force_prepare = true;
    w.start(s, false);
    double last = 0.0, last_elapsed = 0.0;
    int seen = 0;
    for (auto st = w.status(); st.state == FitWorker::State::Preparing; st = w.status()) {
        if (!st.prep.stage.empty()) {
            ++seen;
            CHECK(st.prep.progress >= last);  // never backwards
            CHECK(st.prep.progress <= 1.0);
            CHECK(st.prep.elapsed_s >= last_elapsed);
            last = st.prep.progress;
            last_elapsed = st.prep.elapsed_s;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    CHECK(seen > 0);
    REQUIRE(wait_idle());
    const auto st = w.status(true);
    INFO(st.error);
    CHECK(st.state == FitWorker::State::Ready);
    CHECK(st.prep_s > 0.0);
    // The engine's budget is what the preparation left of the 3 s (a tenth at least).
    CHECK(w.settings().fit.minutes < 0.05);
    CHECK(w.settings().fit.minutes >= 0.005 - 1e-12);
    bool logged = false;
    for (const auto& l : st.log) logged |= l.find("preparation took") != std::string::npos;
    CHECK(logged);
}
