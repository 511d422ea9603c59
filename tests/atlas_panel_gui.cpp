// The Atlas panel (ui/atlas_panel.h) in a real GLFW + OpenGL 3.3 window (run under Xvfb):
// mouse strokes land on the atlas pixels under the cursor, the display shows them (sRGB),
// Ctrl+Z / Ctrl+Shift+Z undo and redo, draw() reports changes, the programmatic API works.
#include <GLFW/glfw3.h>
#include <GL/gl.h>
#include <imgui.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

#include "atlas_panel.h"  // pulls torch, whose glog defines CHECK: doctest's must win
#undef CHECK

#include <doctest/doctest.h>

#include <functional>

#include "io/image_file.h"
#include "test_util.h"

using namespace refocus;

namespace {

// One GLFW window with ImGui; frame(f) runs a UI frame, `f` may set input before NewFrame.
struct Window {
    GLFWwindow* win = nullptr;
    Window() {
        REQUIRE(glfwInit());
        glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
        glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
        glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
        win = glfwCreateWindow(900, 700, "atlas panel test", nullptr, nullptr);
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
    bool frame(AtlasPanel& panel, const std::function<void(ImGuiIO&)>& input = {}) {
        glfwPollEvents();
        ImGui_ImplOpenGL3_NewFrame();
        ImGui_ImplGlfw_NewFrame();
        ImGuiIO& io = ImGui::GetIO();
        if (input) input(io);
        ImGui::NewFrame();
        ImGui::SetNextWindowPos(ImVec2(0, 0));
        ImGui::SetNextWindowSize(io.DisplaySize);
        const bool changed = panel.draw();
        ImGui::Render();
        int w, h;
        glfwGetFramebufferSize(win, &w, &h);
        glViewport(0, 0, w, h);
        glClearColor(0, 0, 0, 1);
        glClear(GL_COLOR_BUFFER_BIT);
        ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
        return changed;
    }
    // Framebuffer RGB at ImGui screen point p (1:1 under Xvfb).
    std::array<int, 3> pixel(std::array<float, 2> p) {
        int w, h;
        glfwGetFramebufferSize(win, &w, &h);
        unsigned char px[4];
        glReadPixels(int(p[0]), h - 1 - int(p[1]), 1, 1, GL_RGBA, GL_UNSIGNED_BYTE, px);
        return {px[0], px[1], px[2]};
    }
};

}  // namespace

TEST_CASE("atlas panel: paint with the mouse, see it, undo/redo with the keyboard") {
    Window w;
    ProjectEdits edits;
    AtlasPanel panel;
    panel.set_edits(&edits);
    Image bg(64, 48, 3, 0.2f);
    panel.set_bases(bg, Image());
    CHECK_FALSE(w.frame(panel));  // the fit's atlas is no edit: opening the panel changes nothing
    CHECK_FALSE(w.frame(panel));
    auto mid = panel.atlas_to_screen(32, 24);
    auto grey = w.pixel(mid);
    CHECK(grey[0] == int(linear_to_srgb8(0.2f)));  // displayed sRGB-encoded

    Brush& b = panel.brush();
    b.color[0] = 1, b.color[1] = 0, b.color[2] = 0;
    b.size = 6, b.hardness = 1, b.opacity = 1;
    auto at = [&](float x, float y, bool down) {
        return [&panel, x, y, down](ImGuiIO& io) {
            auto p = panel.atlas_to_screen(x, y);
            io.MousePos = ImVec2(p[0], p[1]);
            io.MouseDown[0] = down;
        };
    };
    w.frame(panel, at(10.5f, 10.5f, false));  // hover
    bool changed = w.frame(panel, at(10.5f, 10.5f, true));
    for (float x = 12.5f; x <= 40.5f; x += 4) changed |= w.frame(panel, at(x, 10.5f, true));
    w.frame(panel, at(40.5f, 10.5f, false));
    CHECK(changed);
    CHECK(edits.bg.has_edits());
    for (int x = 10; x <= 40; ++x) CHECK(edits.bg.edit().at(x, 10, 3) == 1.0f);
    CHECK(edits.bg.edit().at(25, 20, 3) == 0.0f);
    w.frame(panel, at(60, 40, false));  // move away (no brush outline over the check)
    auto red = w.pixel(panel.atlas_to_screen(25.5f, 10.5f));
    CHECK(red[0] == 255);
    CHECK(red[1] == 0);
    CHECK(w.pixel(panel.atlas_to_screen(25.5f, 30.5f))[0] == grey[0]);

    auto key = [&](bool shift) {
        return [&panel, shift](ImGuiIO& io) {
            auto p = panel.atlas_to_screen(60, 40);
            io.MousePos = ImVec2(p[0], p[1]);
            io.KeyCtrl = true, io.KeyShift = shift;
            io.KeysDown[GLFW_KEY_Z] = true;
        };
    };
    auto release = [](ImGuiIO& io) {
        io.KeysDown[GLFW_KEY_Z] = false, io.KeyCtrl = io.KeyShift = false;
    };
    CHECK(w.frame(panel, key(false)));
    w.frame(panel, release);
    CHECK_FALSE(edits.bg.has_edits());
    CHECK(w.frame(panel, key(true)));
    w.frame(panel, release);
    CHECK(edits.bg.has_edits());

    // Programmatic API and errors.
    b.color[0] = 0, b.color[2] = 1;
    CHECK(panel.paint_stroke(0, {{{50, 40}}, {{60, 40}}}, b));
    CHECK(w.frame(panel));
    CHECK(w.pixel(panel.atlas_to_screen(55.5f, 40.5f))[2] == 255);
    panel.set_bases(Image(64, 48, 3, 0.3f), Image());  // the fit goes on under the paint
    CHECK_FALSE(w.frame(panel));                       // no edit of the artist's
    const fs::path dir = test::scratch_dir("atlas_panel_gui");
    CHECK(panel.export_atlas(0, (dir / "a.png").string(), PixelFormat::Png8));
    CHECK(read_image_file((dir / "a.png").string()).image.width == 64);
    CHECK_FALSE(panel.import_atlas(0, (dir / "missing.png").string()));
    CHECK(panel.error().find("missing.png") != std::string::npos);
    CHECK_FALSE(panel.paint_stroke(1, {{{1, 1}}}, b));  // no foreground atlas
    w.frame(panel);
}
