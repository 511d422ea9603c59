// Settings (fit/settings.h), presets (fit/presets.h), --debug (util/debug.h) and the perframe
// preset as a model with its checkpoint migration.
#include <doctest/doctest.h>
#include <torch/serialize.h>
#include <torch/torch.h>

#include <nlohmann/json.hpp>

#include <functional>

#include "fit/fast_model.h"
#include "fit/fit_engine.h"
#include "session/fit_session.h"
#include "fit/presets.h"
#include "fit/settings.h"
#include "radius/stack_coc.h"
#include "test_util.h"
#include "util/debug.h"
#include "util/error.h"

using namespace refocus;
using namespace refocus::test;

TEST_CASE("settings: a value is checked for its type and range, and stored canonically") {
    Settings s;
    s.set("fast.lr_atlas", "0.02");
    s.set("fast.deblur_path", "off");
    s.set("fast.warp_cell_px", "16");
    s.set("fit.kernel", "disk");
    CHECK(s.value("fast.lr_atlas") == "0.02");
    CHECK(s.value("fast.deblur_path") == "false");
    CHECK(s.value("fast.warp_cell_px") == "16");
    CHECK_THROWS_WITH_AS(s.set("fast.lr_atlas", "fast"), doctest::Contains("not a finite number"),
                         Error);
    CHECK_THROWS_WITH_AS(s.set("fast.lr_atlas", "nan"), doctest::Contains("not a finite number"),
                         Error);
    CHECK_THROWS_WITH_AS(s.set("fast.lr_atlas", "-1"), doctest::Contains("out of range [0, 10]"),
                         Error);
    CHECK_THROWS_WITH_AS(s.set("fast.warp_cell_px", "16.5"), doctest::Contains("not an integer"),
                         Error);
    CHECK_THROWS_WITH_AS(s.set("fast.deblur_path", "maybe"), doctest::Contains("not a bool"),
                         Error);
    CHECK_THROWS_WITH_AS(s.set("fit.kernel", "gauss"), doctest::Contains("pillbox|disk"), Error);
    // An unknown name lists the valid ones.
    CHECK_THROWS_WITH_AS(s.set("fast.lr_atlass", "1"), doctest::Contains("valid: fit.w_reco"),
                         Error);
    CHECK_THROWS_WITH_AS(s.set_assignment("fast.lr_atlas"), doctest::Contains("name=value"), Error);
    CHECK(s.values().size() == 4);  // refused values leave the last good one
}

TEST_CASE("settings: apply_settings sets the fields, and only those set") {
    Settings s;
    s.set("fast.w_tv", "0.004");
    s.set("fast.align_rounds", "0");
    s.set("radius.spectral", "false");
    FastModelOptions fo;
    const FastModelOptions defaults;
    apply_settings(s, fo);
    CHECK(fo.w_tv == doctest::Approx(0.004));
    CHECK(fo.align_rounds == 0);
    CHECK(fo.lr_atlas == defaults.lr_atlas);
    StackCocOptions so;
    apply_settings(s, so);
    CHECK_FALSE(so.spectral);
    CHECK(so.floor_max == StackCocOptions{}.floor_max);
    // Keys of caches hold what was set under their prefix.
    CHECK(s.key("radius.") == "/radius.spectral=false");
    CHECK(Settings{}.key("radius.").empty());
}

TEST_CASE("settings: JSON round trip, and bad JSON names the setting") {
    Settings s;
    s.set("fast.lr_atlas", "0.02");
    s.set("fast.static_align", "false");
    s.set("fit.kernel", "disk");
    s.set("paper.pretrain_map_steps", "10");
    Settings back;
    back.set_json(s.to_json(), "project.json: fit.settings");
    CHECK(back.values() == s.values());
    Settings bad;
    CHECK_THROWS_WITH_AS(
        bad.set_json(nlohmann::json{{"fast.lr_atlas", "x"}}, "p.json: fit.settings"),
        doctest::Contains("p.json: fit.settings: setting fast.lr_atlas"), Error);
    CHECK_THROWS_WITH_AS(bad.set_json(nlohmann::json::array(), "p.json: fit.settings"),
                         doctest::Contains("must be an object"), Error);
    CHECK_THROWS_WITH_AS(bad.set_json(nlohmann::json{{"fast.lr_atlas", {1, 2}}}, "p.json"),
                         doctest::Contains("a number, a bool or a string"), Error);
}

TEST_CASE("settings: the table lists every setting with its default") {
    const std::string t = settings_table();
    for (const auto& i : all_settings()) {
        CHECK(t.find(i.name + " = " + i.def) != std::string::npos);
        CHECK_FALSE(i.help.empty());
    }
    CHECK(t.find("fast.lr_atlas = 0.01") != std::string::npos);
    CHECK(t.find("fit.kernel = pillbox") != std::string::npos);
    CHECK(t.find("fast.pad = the widest blur support") != std::string::npos);
    CHECK(all_settings().size() >= 50);
}

TEST_CASE("presets: one table; unknown names list it") {
    CHECK(preset_names() == "fast|paper|perframe");
    CHECK(find_preset("perframe").has_atlas == false);
    CHECK(find_preset("fast").has_atlas);
    CHECK_THROWS_WITH_AS(find_preset("quick"), doctest::Contains("use fast, paper, perframe"),
                         Error);
    auto d = tiny_two_layer_data(3);
    CHECK_THROWS_AS(make_model("quick", *d, 1), Error);
    FitOptions o;
    o.preset = "quick";
    o.iters = 1;
    CHECK_THROWS_WITH_AS(FitEngine(d, o), doctest::Contains("unknown preset"), Error);
}

TEST_CASE("settings: the engine and the fast model take them") {
    auto d = tiny_two_layer_data(5);
    FitOptions o;
    o.iters = 2;
    o.settings.set("fit.robust_c", "0");
    o.settings.set("fast.pad", "3");
    FitEngine e(d, o);
    CHECK(e.options().robust_c == 0);
    CHECK(e.model().max_pad() == 3);
}

TEST_CASE("debug: known names are set, unknown ones refused with the list") {
    CHECK_THROWS_WITH_AS(set_debug("everything"), doctest::Contains("valid: paper, align"), Error);
    CHECK_THROWS_AS(set_debug("init-atlas"), Error);  // needs a folder
    CHECK_THROWS_AS(set_debug("masks=1"), Error);     // takes none
    set_debug("align,init-atlas=/tmp/x");
    CHECK(debug_enabled("align"));
    CHECK(debug_value("init-atlas") == "/tmp/x");
    CHECK_FALSE(debug_enabled("paper"));
    clear_debug();
    CHECK_FALSE(debug_enabled("align"));
}

TEST_CASE("perframe: a model that steps itself, one frame a step; older checkpoints migrate") {
    auto d = tiny_two_layer_data(7);
    const fs::path dir = scratch_dir("perframe_model");
    FitOptions o;
    o.preset = "perframe";
    o.iters = 100;
    o.settings.set("perframe.iterations", "5");
    FitEngine e(d, o);
    CHECK_FALSE(e.has_atlas());
    CHECK_FALSE(e.frame_done(0));
    e.step();
    e.step();
    CHECK(e.frame_done(0));
    CHECK(e.frame_done(1));
    CHECK_FALSE(e.frame_done(2));
    while (!e.done()) e.step();
    CHECK(e.snapshot().step == d->frames);  // all frames, however large the step budget
    const torch::Tensor sharp1 = e.render_frame(1).sharp.clone();
    CHECK_FALSE(torch::allclose(sharp1, d->input[1].unsqueeze(0)));
    e.save_checkpoint(dir);

    // A version 1 checkpoint: the frames in the archive as "perframe", the flags in the JSON.
    {
        torch::serialize::OutputArchive ar;
        auto frames = d->input.clone();
        frames[1].copy_(sharp1[0]);
        ar.write("perframe", frames);
        ar.save_to((dir / "checkpoint_v1.pt").string());
        nlohmann::json j = nlohmann::json::parse(read_text_file(dir / "checkpoint.json"));
        strip_checksums(j);  // as an earlier build wrote it
        for (const char* key :
             {"residual", "residual_checksums", "optimizer", "optimizer_checksum"})
            j.erase(key);
        j["version"] = 1;
        j["tensors"] = "checkpoint_v1.pt";
        j["perframe_done"] = {false, true, false, false};
        write_file_atomic(dir / "checkpoint.json", j.dump());
    }
    FitEngine r(d, o);
    r.load_checkpoint(dir);
    CHECK(r.frame_done(1));
    CHECK_FALSE(r.frame_done(0));
    CHECK(torch::allclose(r.render_frame(1).sharp, sharp1));
    CHECK(torch::allclose(r.render_frame(0).sharp, d->input[0].unsqueeze(0)));

    // A newer version than this build reads is refused, naming the file.
    nlohmann::json j = nlohmann::json::parse(read_text_file(dir / "checkpoint.json"));
    strip_checksums(j);  // as an earlier build wrote it
    j["version"] = 99;
    write_file_atomic(dir / "checkpoint.json", j.dump());
    FitEngine n(d, o);
    CHECK_THROWS_WITH_AS(n.load_checkpoint(dir),
                         doctest::Contains("checkpoint.json: checkpoint from a newer"), Error);
}

TEST_CASE("cli: --list-settings, --set on fit and bench fit, --debug") {
    RunResult r = cli("fit --list-settings");
    CHECK(r.code == 0);
    CHECK(r.output.find("radius.floor_max = 4.5") != std::string::npos);
    const fs::path dir = scratch_dir("cli_settings");
    r = cli("synth --scene tripod -o '" + (dir / "clip").string() +
            "' --size 48x32 --frames 4 --seed 3");
    REQUIRE(r.code == 0);
    r = cli("new '" + (dir / "clip" / "input_%04d.png").string() + "' -o '" + (dir / "p").string() +
            "'");
    REQUIRE(r.code == 0);
    r = cli("fit '" + (dir / "p").string() + "' --iters 2 --set fast.nope=1");
    CHECK(r.code != 0);
    CHECK(r.output.find("unknown setting 'fast.nope'") != std::string::npos);
    r = cli("fit '" + (dir / "p").string() +
            "' --iters 2 --set fast.lr_atlas=0.02 --set fit.robust_c=2");
    CHECK(r.code == 0);
    const auto j = nlohmann::json::parse(read_text_file(dir / "p" / "project.json"));
    CHECK(j["fit"]["settings"]["fast.lr_atlas"] == 0.02);
    CHECK(j["fit"]["settings"]["fit.robust_c"] == 2.0);
    // A resumed fit keeps them.
    r = cli("fit '" + (dir / "p").string() + "' --iters 3 --resume");
    CHECK(r.code == 0);
    const auto j2 = nlohmann::json::parse(read_text_file(dir / "p" / "project.json"));
    CHECK(j2["fit"]["settings"] == j["fit"]["settings"]);
    r = cli("fit '" + (dir / "p").string() + "' --iters 1 --debug nonsense");
    CHECK(r.code != 0);
    CHECK(r.output.find("--debug: unknown 'nonsense'") != std::string::npos);
    r = cli("bench fit --clip '" + (dir / "clip").string() +
            "' --iters 1 --minutes 100 --at 100 --work '" + (dir / "bench").string() +
            "' --set nope=1");
    CHECK(r.code != 0);
    CHECK(r.output.find("unknown setting 'nope'") != std::string::npos);
}

TEST_CASE(
    "checkpoints: an edited or damaged checkpoint.json is refused as corrupt, naming the field") {
    auto d = tiny_two_layer_data(9);
    const fs::path dir = scratch_dir("checkpoint_corrupt");
    FitOptions o;
    o.iters = 10;
    FitEngine e(d, o);
    e.step();
    e.save_checkpoint(dir);
    const std::string good = read_text_file(dir / "checkpoint.json");
    auto refused = [&](const std::function<void(nlohmann::json&)>& edit, const std::string& field) {
        nlohmann::json j = nlohmann::json::parse(good);
        edit(j);
        write_file_atomic(dir / "checkpoint.json", j.dump());
        FitEngine r(d, o);
        CHECK_THROWS_WITH_AS(
            r.load_checkpoint(dir),
            doctest::Contains(
                ("checkpoint.json: corrupt checkpoint: field '" + field + "'").c_str()),
            Error);
    };
    refused([](nlohmann::json& j) { j["perm"] = {0, 99}; }, "perm");
    refused([](nlohmann::json& j) { j["perm_pos"] = 7; }, "perm_pos");
    refused([](nlohmann::json& j) { j["rng"] = "not a state"; }, "rng");
    refused([](nlohmann::json& j) { j["step"] = -3; }, "step");
    refused([](nlohmann::json& j) { j["elapsed_s"] = "soon"; }, "elapsed_s");
    refused([](nlohmann::json& j) { j["tensors"] = "../../etc/passwd"; }, "tensors");
    write_file_atomic(dir / "checkpoint.json", good);
    FitEngine r(d, o);
    CHECK_NOTHROW(r.load_checkpoint(dir));
    CHECK(r.snapshot().step == 1);
}
