// The studio's document (save, save as, autosave, recovery, recent files, a full disk) and its
// fit thread (fit, stop, checkpoint, render requests, depth, export jobs), without a window.
// LibTorch (through the worker) first: glog's CHECK must not replace doctest's.
#include "project/project.h"
#include "studio/document.h"
#include "studio/fit_worker.h"
#undef CHECK
#include <doctest/doctest.h>

#include <chrono>
#include <cstdlib>
#include <thread>

#include "test_util.h"
#include "util/error.h"

using namespace refocus;
using namespace refocus::test;

namespace {

fs::path tiny_project(const std::string& name) {
    fs::path dir = scratch_dir(name);
    RunResult r = cli("synth --scene tripod -o '" + (dir / "clip").string() +
                      "' --size 64x36 --frames 6 --seed 2");
    INFO(r.output);
    REQUIRE(r.code == 0);
    create_project((dir / "clip/input_%04d.png").string(), dir / "proj", {});
    return dir;
}

// Waits until `pred` holds (polling), failing after `seconds`.
template <class P>
bool wait_for(P pred, double seconds = 120.0) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < end) {
        if (pred()) return true;
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
}

bool idle(const FitWorker& w) {
    auto s = w.status();
    return !s.busy && s.state != FitWorker::State::Preparing &&
           s.state != FitWorker::State::Fitting;
}

}  // namespace

TEST_CASE("document: save, autosave and recovery, save as, recent list") {
    fs::path dir = tiny_project("session_doc");
    setenv("XDG_CONFIG_HOME", dir.c_str(), 1);
    StudioDoc doc;
    doc.open((dir / "proj").string());
    CHECK_FALSE(doc.dirty());
    CHECK(recent_projects().at(0) == fs::absolute(dir / "proj").lexically_normal().string());

    // A change, autosaved but not saved: project.json is untouched, .autosave holds it.
    const std::string before = read_text_file(dir / "proj/project.json");
    doc.focus().focus.set(3, 2.5, Easing::Linear);
    doc.mark_dirty();
    CHECK_FALSE(doc.autosave_if_due(100.0, 60.0));  // the change is stamped now
    CHECK(doc.autosave_if_due(161.0, 60.0));
    CHECK(read_text_file(dir / "proj/project.json") == before);
    CHECK(fs::exists(StudioDoc::autosave_dir(dir / "proj") / "project.json"));

    // "Crash": reopen; the newer autosave is offered and restores the key.
    {
        StudioDoc again;
        again.open((dir / "proj").string());
        CHECK(again.focus().focus.empty());
        REQUIRE(again.has_newer_autosave());
        again.restore_autosave();
        REQUIRE(again.focus().focus.keys.size() == 1);
        CHECK(again.focus().focus.keys[0].value == doctest::Approx(2.5));
        CHECK(again.dirty());
    }

    // Save: the key is in project.json, the autosave is gone.
    doc.save();
    CHECK_FALSE(doc.dirty());
    CHECK_FALSE(fs::exists(StudioDoc::autosave_dir(dir / "proj")));
    {
        StudioDoc again;
        again.open((dir / "proj").string());
        CHECK(again.focus().focus.keys.size() == 1);
        CHECK_FALSE(again.has_newer_autosave());
    }

    // A full disk while saving: an error, and the saved project stays as it was.
    doc.focus().aperture.set(0, 1.0, Easing::Linear);
    doc.mark_dirty();
    const std::string saved = read_text_file(dir / "proj/project.json");
    simulate_disk_full_after(10);
    CHECK_THROWS(doc.save());
    simulate_disk_full_after(-1);
    CHECK(read_text_file(dir / "proj/project.json") == saved);
    CHECK(doc.dirty());

    // Save as: a full copy elsewhere that opens on its own; a non-empty target is refused.
    doc.save_as((dir / "copy").string());
    CHECK(doc.project().dir == fs::absolute(dir / "copy"));
    StudioDoc copy;
    copy.open((dir / "copy").string());
    CHECK(copy.focus().aperture.keys.size() == 1);
    CHECK(copy.project().read_frame(5).width == 64);
    try {
        doc.save_as((dir / "proj").string());
        FAIL("save as into a non-empty folder must fail");
    } catch (const Error& e) {
        CHECK(std::string(e.what()).find("not empty") != std::string::npos);
    }
    CHECK(recent_projects().at(0) == fs::absolute(dir / "copy").lexically_normal().string());

    // The studio runs Save As in steps, the copy on its worker: a target inside the project is
    // refused; the copy leaves the autosave behind, reports progress and can be cancelled; the
    // document moves only when it is finished.
    auto message_of = [](auto&& f) -> std::string {
        try {
            f();
        } catch (const Error& e) {
            return e.what();
        }
        return "";
    };
    CHECK(message_of([&] {
              doc.save_as_target((dir / "copy" / "inner").string());
          }).find("inside the project") != std::string::npos);
    fs::create_directories(doc.project().dir / ".autosave");
    write_file_atomic(doc.project().dir / ".autosave" / "project.json", "{}");
    int calls = 0, total = -1;
    StudioDoc::copy_project_files(doc.project().dir, dir / "copy2", [&](int, int n) {
        ++calls;
        total = n;
        return true;
    });
    CHECK(total > 3);
    CHECK(calls == total + 1);
    CHECK(fs::exists(dir / "copy2" / "project.json"));
    CHECK(fs::exists(dir / "copy2" / "frames"));
    CHECK_FALSE(fs::exists(dir / "copy2" / ".autosave"));
    CHECK(message_of([&] {
              StudioDoc::copy_project_files(doc.project().dir, dir / "copy3",
                                            [](int i, int) { return i < 1; });
          }).find("cancelled") != std::string::npos);
    CHECK(doc.project().dir == fs::absolute(dir / "copy"));
    doc.finish_save_as(fs::absolute(dir / "copy2"));
    CHECK(doc.project().dir == fs::absolute(dir / "copy2"));
    StudioDoc reopened;
    reopened.open((dir / "copy2").string());
    CHECK(reopened.focus().aperture.keys.size() == 1);
}

TEST_CASE("fit worker: fit on its thread, render between steps, stop keeps the work") {
    fs::path dir = tiny_project("session_worker");
    Project p = Project::load(dir / "proj");
    FitWorker w;
    w.open(p);
    REQUIRE(wait_for([&] { return idle(w); }));
    CHECK(w.status().state == FitWorker::State::Unfitted);
    CHECK_FALSE(w.has_checkpoint());

    FitSettings s;
    s.fit.iters = 8;
    w.start(s, false);
    REQUIRE(wait_for([&] { return w.status().state == FitWorker::State::Fitting; }));
    REQUIRE(wait_for([&] { return idle(w); }));
    auto st = w.status();
    INFO(st.error);
    CHECK(st.state == FitWorker::State::Ready);
    CHECK(st.snap.step == 8);
    CHECK(w.status(true).history.size() == 8);
    CHECK(w.status().history.empty());  // the light status does not copy it
    CHECK(w.has_checkpoint());
    CHECK(FitEngine::has_checkpoint(fit_dir(p)));

    // Render requests are answered on the worker thread.
    auto pending = w.frame_async(3);
    REQUIRE(pending.wait_for(std::chrono::seconds(30)) == std::future_status::ready);
    std::optional<FitWorker::ViewFrame> v = pending.get();
    REQUIRE(v.has_value());
    CHECK(v->t == 3);
    CHECK(v->maps.sharp.width == 64);
    CHECK(v->maps.uv_bg.channels == 2);
    CHECK(v->radius.channels == 1);
    w.request_atlases();
    std::optional<FitWorker::Atlases> a;
    REQUIRE(wait_for([&] { return (a = w.take_atlases()).has_value(); }, 30));
    CHECK(a->bg.channels == 3);

    // Depth: fitted once, saved, then loaded for the same checkpoint.
    w.request_depth();
    REQUIRE(wait_for([&] { return w.depth() != nullptr; }, 60));
    CHECK(DepthModel::exists(depth_dir(p.dir)));
    CHECK(w.depth()->frames() == 6);

    // Continue with a long budget, stop after some steps: checkpointed where it stopped.
    s.fit.iters = 0;
    s.fit.minutes = 30;
    w.start(s, true);
    REQUIRE(wait_for([&] { return w.status().snap.step >= 11; }, 60));
    w.stop();
    REQUIRE(wait_for([&] { return idle(w); }));
    st = w.status();
    CHECK(st.state == FitWorker::State::Ready);
    CHECK(st.snap.step > 10);
    CHECK(st.snap.step < 1000);

    // The document and the fit thread write project.json sections of their own: neither undoes
    // the other's (the worker's Project copy predates the document's save).
    {
        StudioDoc doc;
        doc.open((dir / "proj").string());
        doc.focus().focus.set(1, 0.5, Easing::Linear);
        doc.mark_dirty();
        doc.save();
        // Two more steps. Waited for by their outcome: the Fitting state of a 2-step run can
        // come and go between two polls.
        const int64_t before = w.status().snap.step;
        s.fit.minutes = 0;
        s.fit.iters = before + 2;
        w.start(s, true);
        REQUIRE(wait_for([&] { return w.status().snap.step >= before + 2 && idle(w); }));
        Project after = Project::load(dir / "proj");
        CHECK(after.sections.contains("focus"));
        CHECK(after.sections.at("focus").at("focus").size() == 1);
        const int64_t fitted = after.sections.at("fit").at("status").at("step").get<int64_t>();
        CHECK(fitted == w.status().snap.step);
        doc.save();  // a later save keeps the fit's status
        CHECK(
            Project::load(dir / "proj").sections.at("fit").at("status").at("step").get<int64_t>() ==
            fitted);
    }

    // A job reports its outcome; errors in jobs land in the status, the worker lives on.
    w.post("boom", [](FitEngine*, const Project&) { throw Error("deliberate failure"); });
    REQUIRE(wait_for([&] { return w.status().error.find("deliberate") != std::string::npos; }, 10));
    w.post("export", [&](FitEngine* e, const Project& proj) {
        ExportOptions o;
        o.project = &proj;
        o.first = 1;
        o.last = 2;
        auto files = export_pass(*e, ExportPass::Refocus, "png", (dir / "out").string(), o);
        w.post_result(std::to_string(files.size()));
    });
    std::optional<std::string> r;
    REQUIRE(wait_for([&] { return (r = w.take_result()).has_value(); }, 60));
    CHECK(*r == "2");
    CHECK(fs::exists(dir / "out/refocus_0001.png"));
    CHECK_FALSE(fs::exists(dir / "out/refocus_0002.png"));
}

TEST_CASE("fit worker: closing during a fit checkpoints it; reopening loads it") {
    fs::path dir = tiny_project("session_close");
    Project p = Project::load(dir / "proj");
    int64_t reached = 0;
    {
        FitWorker w;
        w.open(p);
        FitSettings s;
        s.fit.minutes = 30;
        w.start(s, false);
        REQUIRE(wait_for([&] { return w.status().snap.step >= 3; }, 60));
        reached = w.status().snap.step;
    }  // destructor: stop, checkpoint, join
    FitWorker w;
    w.open(p);
    REQUIRE(wait_for([&] { return idle(w) && w.has_engine(); }, 60));
    const int64_t reopened = w.status().snap.step;
    CHECK(reopened >= reached);
    // Continue fitting: the engines open from the checkpoint (restoring_options) and go on from
    // its step.
    FitSettings more;
    more.fit.iters = 3;
    w.start(more, true);
    REQUIRE(wait_for([&] { return idle(w) && w.status().snap.step >= reopened + 3; }, 120));
    CHECK(w.status().snap.step == reopened + 3);
}
