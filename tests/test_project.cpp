// Project files: creation from clips, info, validation, atomic saves.
#include <doctest/doctest.h>

#include <fstream>

#include "io/clip.h"
#include "project/project.h"
#include "test_util.h"
#include "util/error.h"

using namespace refocus;
using namespace refocus::test;
using nlohmann::json;

namespace {

fs::path make_mp4(const fs::path& dir, int n) {
    ClipWriteOptions o;
    o.fps = 30;
    ClipWriter w((dir / "shot.mp4").string(), "shot", ClipFormat::Mp4, o);
    for (int i = 0; i < n; ++i) w.write(pattern_frame(64, 36, i));
    w.finish();
    return dir / "shot.mp4";
}

// Writes a modified copy of a valid project's JSON and returns the load error message.
std::string load_error(const fs::path& proj, const std::function<void(json&)>& edit) {
    json j = json::parse(read_text_file(proj / "project.json"));
    edit(j);
    std::ofstream(proj / "project.json") << j.dump(2);
    try {
        Project::load(proj);
    } catch (const Error& e) {
        return e.what();
    }
    return "";
}

}  // namespace

TEST_CASE("refocus new and info on an mp4 and on a PNG sequence") {
    fs::path dir = scratch_dir("project_new");
    fs::path mp4 = make_mp4(dir, 6);
    RunResult r = cli("new '" + mp4.string() + "' -o '" + (dir / "p_mp4").string() + "'");
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = cli("info '" + (dir / "p_mp4").string() + "'");
    CHECK(r.code == 0);
    CHECK(r.output.find("64x36") != std::string::npos);
    CHECK(r.output.find("frames:   6") != std::string::npos);
    CHECK(r.output.find("30.000") != std::string::npos);
    Project p = Project::load(dir / "p_mp4");
    CHECK(p.frames == 6);
    CHECK(p.source == "../shot.mp4");  // relative to the project folder
    // The cache holds what the clip decodes to (half precision).
    auto clip = ClipReader::open(mp4.string());
    CHECK(max_abs_diff(p.read_frame(4), clip->read(4)) < 2e-3);

    std::vector<Image> frames;
    for (int i = 0; i < 5; ++i) frames.push_back(pattern_frame(40, 24, i));
    write_png_sequence(dir / "seq", frames);
    r = cli("new '" + (dir / "seq" / "frame_%04d.png").string() + "' -o '" +
            (dir / "p_seq").string() + "' --fps 12");
    INFO(r.output);
    REQUIRE(r.code == 0);
    r = cli("info '" + (dir / "p_seq").string() + "'");
    CHECK(r.output.find("40x24") != std::string::npos);
    CHECK(r.output.find("frames:   5") != std::string::npos);
    CHECK(r.output.find("12.000") != std::string::npos);
    // info on the raw clip
    r = cli("info '" + (dir / "seq").string() + "'");
    CHECK(r.code == 0);
    CHECK(r.output.find("sequence") != std::string::npos);
    // A second `new` into the same folder is refused and leaves the project alone.
    r = cli("new '" + mp4.string() + "' -o '" + (dir / "p_seq").string() + "'");
    CHECK(r.code != 0);
    CHECK(r.output.find("already exists") != std::string::npos);
    CHECK(Project::load(dir / "p_seq").frames == 5);
    // The project folder can move: every path inside is relative.
    fs::rename(dir / "p_seq", dir / "moved");
    CHECK(Project::load(dir / "moved").read_frame(2).width == 40);
}

TEST_CASE("project validation names the field") {
    fs::path dir = scratch_dir("project_validate");
    fs::path mp4 = make_mp4(dir, 2);
    create_project(mp4.string(), dir / "p", {});
    const fs::path p = dir / "p";
    const std::string good = read_text_file(p / "project.json");
    auto restore = [&] { std::ofstream(p / "project.json") << good; };

    CHECK(load_error(p, [](json& j) { j["version"] = 99; }).find("newer Refocus") !=
          std::string::npos);
    restore();
    CHECK(load_error(p, [](json& j) { j["clip"]["width"] = -3; }).find("'clip.width'") !=
          std::string::npos);
    restore();
    CHECK(load_error(p, [](json& j) {
              j["clip"].erase("frames");
          }).find("'clip.frames' is missing") != std::string::npos);
    restore();
    CHECK(load_error(p, [](json& j) {
              j["clip"]["fps"] = "fast";
          }).find("'clip.fps' must be a number") != std::string::npos);
    restore();
    CHECK(load_error(p, [](json& j) {
              j["cache"]["frames"] = "/etc/frame_%d.exr";
          }).find("'cache.frames'") != std::string::npos);
    restore();
    CHECK(load_error(p, [](json& j) { j["source"]["kind"] = "film"; }).find("'source.kind'") !=
          std::string::npos);
    restore();
    std::ofstream(p / "project.json") << "{ \"version\": 1, ";
    try {
        Project::load(p);
        FAIL("truncated JSON loaded");
    } catch (const Error& e) {
        CHECK(std::string(e.what()).find("not valid JSON") != std::string::npos);
        CHECK(std::string(e.what()).find("project.json") != std::string::npos);
    }
    restore();
    fs::remove(p / "frames" / "frame_0001.exr");
    CHECK_THROWS_WITH_AS(Project::load(p), doctest::Contains("frame_0001.exr"), Error);
    RunResult r = cli("info '" + (dir / "empty").string() + "'");
    CHECK(r.code != 0);
}

TEST_CASE("sections of later stages survive a load/save round trip") {
    fs::path dir = scratch_dir("project_sections");
    Project p = create_project(make_mp4(dir, 2).string(), dir / "p", {});
    p.sections["focus"] = {{"keyframes", json::array({1, 2, 3})}};
    p.save();
    Project q = Project::load(dir / "p");
    CHECK(q.sections["focus"]["keyframes"].size() == 3);
    CHECK(q.to_json() == p.to_json());
}

TEST_CASE("a save that hits a full disk keeps the previous project file") {
    fs::path dir = scratch_dir("project_diskfull");
    Project p = create_project(make_mp4(dir, 2).string(), dir / "p", {});
    const std::string before = read_text_file(dir / "p" / "project.json");
    p.name = "renamed";
    p.sections["notes"] = std::string(5000, 'x');
    simulate_disk_full_after(100);
    CHECK_THROWS_WITH_AS(p.save(), doctest::Contains("project.json"), Error);
    simulate_disk_full_after(-1);
    CHECK(read_text_file(dir / "p" / "project.json") == before);
    size_t n = std::distance(fs::directory_iterator(dir / "p"), fs::directory_iterator());
    CHECK(n == 2);  // project.json and frames/: no temporary left behind
    p.save();
    CHECK(Project::load(dir / "p").name == "renamed");
}
