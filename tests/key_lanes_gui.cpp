// The timeline's key lanes (ui/key_lanes.h) in a real GLFW + OpenGL 3.3 window (run under Xvfb),
// driven with ImGui input: a click selects a key, Shift+click adds one, a drag moves the selected
// keys in whole frames (clamped to the clip) as one undo entry, a click elsewhere moves the
// playhead, Delete removes, Ctrl+C / Ctrl+V paste at the playhead, right-click opens a key's menu.
#include <GLFW/glfw3.h>
#include <GL/gl.h>
#include <imgui.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

#include "key_lanes.h"  // pulls torch, whose glog defines CHECK: doctest's must win
#include "studio_context.h"
#undef CHECK

#include <doctest/doctest.h>

#include <functional>

#include "test_util.h"

using namespace refocus;

namespace {

// One GLFW window with ImGui drawing the lanes; frame(f) runs a UI frame, `f` sets the input.
struct Window {
    GLFWwindow* win = nullptr;
    ImVec2 origin, size;  // where the lanes were drawn
    Window() {
        REQUIRE(glfwInit());
        glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
        glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
        glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
        win = glfwCreateWindow(900, 300, "key lanes test", nullptr, nullptr);
        REQUIRE(win);
        glfwMakeContextCurrent(win);
        ImGui::CreateContext();
        ImGui::GetIO().IniFilename = nullptr;
        ImGui_ImplGlfw_InitForOpenGL(win, false);  // no callbacks: the test drives the input
        ImGui_ImplOpenGL3_Init("#version 330 core");
    }
    ~Window() {
        ImGui_ImplOpenGL3_Shutdown();
        ImGui_ImplGlfw_Shutdown();
        ImGui::DestroyContext();
        glfwDestroyWindow(win);
        glfwTerminate();
    }
    void frame(KeyLaneState& s, StudioContext& ctx, const std::function<void(ImGuiIO&)>& input) {
        glfwPollEvents();
        ImGui_ImplOpenGL3_NewFrame();
        ImGui_ImplGlfw_NewFrame();
        ImGuiIO& io = ImGui::GetIO();
        io.MouseDown[0] = io.MouseDown[1] = false;
        io.KeyCtrl = io.KeyShift = false;
        for (bool& k : io.KeysDown) k = false;
        if (input) input(io);
        ImGui::NewFrame();
        ImGui::SetNextWindowPos(ImVec2(0, 0));
        ImGui::SetNextWindowSize(io.DisplaySize);
        ImGui::Begin("Timeline");
        origin = ImGui::GetCursorScreenPos();
        size = ImGui::GetContentRegionAvail();
        draw_key_lanes(s, ctx, origin, size);
        ImGui::End();
        ImGui::Render();
        int w, h;
        glfwGetFramebufferSize(win, &w, &h);
        glViewport(0, 0, w, h);
        glClear(GL_COLOR_BUFFER_BIT);
        ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
    }
};

std::vector<int> frames_of(const Lane& l) {
    std::vector<int> f;
    for (const Keyframe& k : l.keys) f.push_back(k.frame);
    return f;
}

// Mouse and keyboard on the lanes of a 20-frame clip, as a user's hands would.
struct Hands {
    Window& w;
    KeyLaneState& s;
    StudioContext& ctx;
    // The screen point of a key (the lanes' geometry: 110 px of labels, 18 px rows).
    ImVec2 at(int lane, double frame) const {
        const float lane_w = w.size.x - 110.0f;
        return ImVec2(w.origin.x + 110.0f + static_cast<float>((frame + 0.5) / 20.0) * lane_w,
                      w.origin.y + lane * 18.0f + 9.0f);
    }
    void mouse(ImVec2 p, bool down, bool shift = false, int button = 0) {
        w.frame(s, ctx, [=](ImGuiIO& io) {
            io.MousePos = p;
            io.MouseDown[button] = down;
            io.KeyShift = shift;
        });
    }
    void click(ImVec2 p, bool shift = false, int button = 0) {
        mouse(p, false, shift, button);
        mouse(p, true, shift, button);
        mouse(p, false, shift, button);
    }
    void drag(ImVec2 from, ImVec2 to) {
        mouse(from, false);
        mouse(from, true);
        for (int i = 1; i <= 4; ++i) {
            const float u = i / 4.0f;
            mouse(ImVec2(from.x + u * (to.x - from.x), from.y + u * (to.y - from.y)), true);
        }
        mouse(to, false);
    }
    void key(int glfw_key, bool ctrl = false) {
        w.frame(s, ctx, [=](ImGuiIO& io) {
            io.MousePos = ImVec2(5, 280);
            io.KeysDown[glfw_key] = true;
            io.KeyCtrl = ctrl;
        });
        w.frame(s, ctx, [](ImGuiIO& io) { io.MousePos = ImVec2(5, 280); });
    }
};

}  // namespace

TEST_CASE("key lanes: select, drag, delete, copy and paste with mouse and keys") {
    const fs::path dir = test::scratch_dir("key_lanes_gui");
    std::vector<Image> frames;
    for (int i = 0; i < 20; ++i) frames.push_back(test::pattern_frame(32, 18, i));
    test::write_png_sequence(dir / "seq", frames);
    create_project((dir / "seq").string(), dir / "proj", {});
    setenv("XDG_CONFIG_HOME", dir.c_str(), 1);

    Window w;
    StudioContext ctx;
    ctx.doc.open((dir / "proj").string());
    ctx.source = std::make_unique<FrameSource>((dir / "proj").string());
    FocusTrack& t = ctx.doc.focus();
    t.focus.set(2, 1.0);
    t.focus.set(10, 3.0);
    t.aperture.set(5, 1.0);
    ctx.doc.commit("setup");
    KeyLaneState s;
    w.frame(s, ctx, {});
    Hands h{w, s, ctx};
    auto at = [&](int lane, double frame) { return h.at(lane, frame); };

    // A click selects; Shift+click adds.
    h.click(at(0, 2));
    REQUIRE(s.selected.size() == 1);
    CHECK(s.selected[0] == KeyRef{0, 2});
    h.click(at(1, 5), true);
    CHECK(s.selected.size() == 2);

    // A drag of the selection by 3 frames: both keys move, one undo entry.
    h.drag(at(1, 5), at(1, 8));
    CHECK(frames_of(t.focus) == std::vector<int>{5, 10});
    CHECK(frames_of(t.aperture) == std::vector<int>{8});
    CHECK(ctx.doc.undo_label() == "Move 2 keys");
    CHECK(ctx.doc.dirty());
    REQUIRE(ctx.doc.undo());
    CHECK(frames_of(t.focus) == std::vector<int>{2, 10});
    CHECK(frames_of(t.aperture) == std::vector<int>{5});
    CHECK(ctx.doc.undo_label() == "setup");
    REQUIRE(ctx.doc.redo());

    // Dragged past the clip's end: clamped (the last selected key lands on the last frame).
    h.drag(at(1, 8), at(1, 40));
    CHECK(frames_of(t.aperture) == std::vector<int>{19});
    CHECK(frames_of(t.focus) == std::vector<int>{10, 16});

    // A click where there is no key moves the playhead and clears the selection.
    h.click(at(2, 12));
    CHECK(ctx.frame == 12);
    CHECK(s.selected.empty());

    // Copy two keys, paste at the playhead (their spacing kept), delete one.
    h.click(at(0, 10));
    h.click(at(0, 16), true);
    h.key(GLFW_KEY_C, true);
    ctx.set_frame(1);
    h.key(GLFW_KEY_V, true);
    CHECK(frames_of(t.focus) == std::vector<int>{1, 7, 10, 16});
    CHECK(ctx.doc.undo_label() == "Paste 2 keys");
    CHECK(s.selected.size() == 2);  // the pasted keys
    h.click(at(0, 7));
    h.key(GLFW_KEY_DELETE);
    CHECK(frames_of(t.focus) == std::vector<int>{1, 10, 16});
    CHECK(ctx.doc.undo_label() == "Delete key");

    // Right-click a key: its menu opens for it.
    h.click(at(0, 16), false, 1);
    CHECK(s.menu_key == KeyRef{0, 16});
    CHECK(ImGui::IsPopupOpen("", ImGuiPopupFlags_AnyPopupId));
}
