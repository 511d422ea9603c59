// The studio document's undo history of the focus track (add, undo, redo, a new change cutting
// the redo branch, a drag as one entry, saving keeps it), the autosave offered after a crash
// during a fit, and the easing curves the keys use. No window.
// LibTorch (through the document's edits) first: glog's CHECK must not replace doctest's.
#include "project/project.h"
#include "session/fit_session.h"
#include "studio/document.h"
#undef CHECK
#include <doctest/doctest.h>

#include <chrono>
#include <cstdlib>

#include "test_util.h"

using namespace refocus;
using namespace refocus::test;

namespace {

// A 6-frame project made from pattern frames (no fit).
fs::path small_project(const std::string& name) {
    const fs::path dir = scratch_dir(name);
    std::vector<Image> frames;
    for (int i = 0; i < 6; ++i) frames.push_back(pattern_frame(32, 18, i));
    write_png_sequence(dir / "seq", frames);
    create_project((dir / "seq").string(), dir / "proj", {});
    setenv("XDG_CONFIG_HOME", dir.c_str(), 1);  // the recent list goes to the scratch folder
    return dir / "proj";
}

}  // namespace

TEST_CASE("document undo: add, undo, redo, a new change cuts redo, saving keeps the history") {
    StudioDoc doc;
    doc.open(small_project("doc_undo").string());
    CHECK_FALSE(doc.can_undo());
    CHECK_FALSE(doc.commit("nothing"));  // no change: no entry

    doc.focus().focus.set(0, 1.0);
    CHECK(doc.commit("Key focus"));
    doc.focus().focus.set(5, 3.0);
    CHECK(doc.commit("Key focus at 5"));
    CHECK(doc.undo_label() == "Key focus at 5");

    REQUIRE(doc.undo());
    CHECK(doc.focus().focus.keys.size() == 1);
    CHECK(doc.dirty());
    CHECK(doc.redo_label() == "Key focus at 5");
    REQUIRE(doc.redo());
    CHECK(doc.focus().focus.keys.size() == 2);
    CHECK_FALSE(doc.redo());

    // Undo, then a new change: the undone branch cannot be redone.
    REQUIRE(doc.undo());
    doc.focus().aperture.set(2, 1.5);
    CHECK(doc.commit("Key aperture"));
    CHECK_FALSE(doc.can_redo());
    CHECK(doc.focus().focus.keys.size() == 1);

    // A drag changes the track every frame and commits once, on release: one entry.
    for (int f = 1; f <= 4; ++f) {
        doc.focus().focus.keys[0].frame = f;
        doc.mark_dirty();
    }
    CHECK(doc.commit("Move key"));
    REQUIRE(doc.undo());
    CHECK(doc.focus().focus.keys[0].frame == 0);
    REQUIRE(doc.redo());
    CHECK(doc.focus().focus.keys[0].frame == 4);

    // A change not committed yet is committed by undo, then undone.
    doc.focus().blades.set(0, 6);
    REQUIRE(doc.undo());
    CHECK(doc.focus().blades.empty());
    CHECK(doc.undo_label() == "Move key");

    // Saving keeps the history: undo after a save goes on undoing (and dirties the document).
    doc.save();
    CHECK_FALSE(doc.dirty());
    CHECK(doc.can_undo());
    REQUIRE(doc.undo());
    CHECK(doc.focus().focus.keys[0].frame == 0);
    CHECK(doc.dirty());
    REQUIRE(doc.undo());  // "Key aperture"
    CHECK(doc.focus().aperture.empty());
    REQUIRE(doc.undo());  // "Key focus"
    CHECK(doc.focus().focus.empty());
    CHECK_FALSE(doc.undo());

    // The tracked point is part of the track.
    doc.focus().track = FocusTarget{0, 0.1f, 0.2f, 0, 5};
    CHECK(doc.commit("Track a point"));
    REQUIRE(doc.undo());
    CHECK_FALSE(doc.focus().track.has_value());

    // Opening a project starts a new history.
    doc.open(doc.project().dir.string());
    CHECK_FALSE(doc.can_undo());
    CHECK_FALSE(doc.can_redo());
}

TEST_CASE("autosave: offered after a crash during a fit, whatever the file times") {
    const fs::path proj = small_project("doc_autosave_fit");
    StudioDoc doc;
    doc.open(proj.string());
    doc.focus().focus.set(0, 1.0);
    doc.mark_dirty();
    doc.save();

    // A key changed and autosaved; then the fit rewrites project.json (its "fit" section), so
    // project.json is newer than the autosave. Then the studio is killed.
    doc.focus().focus.set(3, 2.5);
    doc.mark_dirty();
    CHECK_FALSE(doc.autosave_if_due(10.0, 1.0));
    REQUIRE(doc.autosave_if_due(12.0, 1.0));
    const fs::path as = StudioDoc::autosave_dir(proj) / Project::kFileName;
    fs::last_write_time(as, fs::last_write_time(as) - std::chrono::hours(1));
    Project fit_side = Project::load(proj);
    FitSettings fs_settings;
    fs_settings.fit.minutes = 5;
    write_fit_settings(fit_side, fs_settings, nullptr);
    REQUIRE(fs::last_write_time(proj / Project::kFileName) > fs::last_write_time(as));

    StudioDoc again;
    again.open(proj.string());
    CHECK(again.focus().focus.keys.size() == 1);
    REQUIRE(again.has_newer_autosave());
    again.restore_autosave();
    REQUIRE(again.focus().focus.keys.size() == 2);
    CHECK(again.focus().focus.keys[1].frame == 3);
    CHECK(again.focus().focus.keys[1].value == doctest::Approx(2.5));
    CHECK(again.dirty());

    // An autosave holding the saved work is not offered, however new it is.
    again.save();
    again.mark_dirty();
    REQUIRE(again.autosave_if_due(0.5, 0.0));
    StudioDoc third;
    third.open(proj.string());
    CHECK_FALSE(third.has_newer_autosave());
}

TEST_CASE("easing: ease in and ease out (quadratic), names in project.json") {
    Lane lane;
    lane.set(0, 0.0, Easing::EaseIn);
    lane.set(10, 4.0, Easing::EaseOut);
    lane.set(20, 8.0);
    CHECK(lane.eval(0, 9) == 0.0);
    CHECK(lane.eval(5, 9) == doctest::Approx(1.0));      // 4 · (1/2)²
    CHECK(lane.eval(2.5, 9) == doctest::Approx(0.25));   // 4 · (1/4)²
    CHECK(lane.eval(10, 9) == doctest::Approx(4.0));     // reaches the key
    CHECK(lane.eval(15, 9) == doctest::Approx(7.0));     // 4 + 4 · (1 − (1/2)²)
    CHECK(lane.eval(12.5, 9) == doctest::Approx(5.75));  // 4 + 4 · (1 − (3/4)²)
    // Monotone between the keys: no overshoot.
    double last = -1;
    for (double f = 0; f <= 20; f += 0.25) {
        const double v = lane.eval(f, 9);
        CHECK(v >= last);
        last = v;
    }
    FocusTrack ft;
    ft.focus = lane;
    const FocusTrack back = FocusTrack::from_json(nlohmann::json::parse(ft.to_json().dump()), "p");
    CHECK(back.focus.keys[0].easing == Easing::EaseIn);
    CHECK(back.focus.keys[1].easing == Easing::EaseOut);
    CHECK(ft.to_json()["focus"][0]["easing"] == "ease_in");
    Easing e = Easing::Linear;
    CHECK(parse_easing_name("ease_out", e));
    CHECK(e == Easing::EaseOut);
    CHECK_FALSE(parse_easing_name("bounce", e));
}
